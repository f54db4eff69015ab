"""``teamslam paper``: the papers' values file against the papers' text, and each reproduction
on a tiny setting (its cells, their values against the library run directly)."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_data_dir
from teamslam.cli import main
from teamslam.paper import ITEMS, PaperSettings, Reproducer, paper_values, reproduce_all

ROMAN = ("I", "II", "III", "IV")


def _papers_dir() -> Path:
    env = os.environ.get("TEAMSLAM_PAPERS")
    return Path(env) if env else shared_data_dir().parent / "papers"


def _paper_text(name: str) -> str:
    path = _papers_dir() / name
    if not path.is_file():
        pytest.skip(f"paper text not found at {path} (set TEAMSLAM_PAPERS to its directory)")
    return path.read_text()


def _clean(text: str) -> str:
    text = re.sub(r"</?b>", "", text)
    text = re.sub(r"\$\\operatorname\{(\w+)\}\$", r"\1", text)
    return text.replace("<br>", " ").strip()


def _dvi_tables(text: str) -> dict[str, dict[tuple[str, str], str]]:
    """Every ``TABLE N:`` of the DVI paper: the tab-separated lines after the caption."""
    lines = text.splitlines()
    tables = {}
    for k, line in enumerate(lines):
        m = re.match(r"TABLE ([IV]+):", line)
        if not m:
            continue
        j = k + 1
        while not lines[j].strip():
            j += 1
        header = lines[j].split("\t")[1:]
        cells = {}
        for row in lines[j + 1 :]:
            if "\t" not in row:
                break
            label, *values = row.split("\t")
            assert len(values) == len(header), row
            for column, value in zip(header, values, strict=True):
                if m.group(1) == "IV":
                    column = f"{column} robots"
                cells[_clean(label), column] = _clean(value)
        tables[m.group(1)] = cells
    return tables


def _fej_tables(text: str) -> dict[str, dict[tuple[str, str], str]]:
    """Every pipe table of the FEJ paper, named by the ``Table N:`` caption that follows it."""
    lines = text.splitlines()
    tables = {}
    k = 0
    while k < len(lines):
        if not lines[k].startswith("|"):
            k += 1
            continue
        start = k
        while k < len(lines) and lines[k].startswith("|"):
            k += 1
        rows = [[_clean(c) for c in line.strip().strip("|").split("|")] for line in lines[start:k]]
        caption = next(line for line in lines[k:] if re.match(r"Table \d+:", line))
        number = re.match(r"Table (\d+):", caption).group(1)
        # three header lines (after the --- line): who (Robot 1, Robot 2, Feature), what, metric
        group = ""
        columns = []
        for c in range(2, len(rows[0])):
            found = re.search(r"(Robot \d|Feature)", rows[0][c])
            group = found.group(1) if found else group
            columns.append(f"{group} {rows[2][c]} {rows[3][c]}")
        cells = {}
        label = ""
        for row in rows[4:]:
            label = row[0] or label
            for column, value in zip(columns, row[2:], strict=True):
                cells[f"{label} {row[1]}", column] = value
        tables[number] = cells
    return tables


def _ours(paper: str, table: str) -> dict[tuple[str, str], str]:
    return {(v.row, v.column): v.text for v in paper_values(paper, table)}


def test_dvi_values_are_the_papers():
    tables = _dvi_tables(_paper_text("distributed-msckf-dvi.md"))
    assert sorted(tables) == sorted(ROMAN)
    for name, cells in tables.items():
        assert _ours("dvi", name) == cells, f"Table {name}"
    assert {v.table for v in paper_values("dvi")} == set(ROMAN)


def test_fej_values_are_the_papers():
    tables = _fej_tables(_paper_text("fej-ekf-multirobot.md"))
    assert sorted(tables) == ["1", "2"]
    for name, cells in tables.items():
        assert len(cells) == 72
        assert _ours("fej", name) == cells, f"Table {name}"


def test_published_code_values_are_the_data_readme():
    readme = shared_data_dir() / "README.md"
    if not readme.is_file():
        pytest.skip(f"data README not found at {readme}")
    m = re.search(
        r"robot-1 position RMSE (\S+) m \(Std\) and (\S+) m \(FEJ\), robot-2 (\S+) m / (\S+) m",
        " ".join(readme.read_text().split()),
    )
    assert m is not None
    ours = _ours("fej", "victoria-park")
    assert ours == {
        ("Std-EKF", "Robot 1 Position RMSE"): m.group(1),
        ("FEJ-EKF", "Robot 1 Position RMSE"): m.group(2),
        ("Std-EKF", "Robot 2 Position RMSE"): m.group(3),
        ("FEJ-EKF", "Robot 2 Position RMSE"): m.group(4),
    }


def test_every_value_names_its_unit_and_parses():
    values = paper_values()
    assert len(values) == 60 + 40 + 40 + 20 + 2 * 72 + 4
    for v in values:
        assert v.unit in ("m", "rad", "s", "")
        assert math.isfinite(v.value) and v.digits >= 2
        assert v.source in ("paper", "published code")


def test_paper_list(capsys):
    assert main(["paper", "list"]) == 0
    out = capsys.readouterr().out
    for key in ITEMS:
        assert key in out
    assert main(["paper", "list", "--json"]) == 0
    listing = json.loads(capsys.readouterr().out)
    assert [r["key"] for r in listing] == list(ITEMS)
    counts = {r["key"]: r["paper_values"] for r in listing}
    assert counts["dvi-table-1"] == 60 and counts["fej-table-2"] == 72


@pytest.mark.parametrize(
    "argv",
    [
        ["paper", "dvi", "--table", "5"],
        ["paper", "fej", "--figure", "3"],
        ["paper", "dvi", "--table", "1", "--figure", "3"],
        ["paper", "fej", "--table", "1", "--features", "30"],
        ["paper", "all"],
    ],
)
def test_wrong_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def _records(capsys) -> dict[tuple[str, str], dict]:
    records = json.loads(capsys.readouterr().out)
    return {(r["row"], r["column"]): r for r in records}


def test_fej_table_1_json_is_the_monte_carlo(shared_data, capsys):
    """The 20-feature rows are the published environment's Monte Carlo (the same numbers as
    ``teamslam fej table`` on those files), with ours − theirs; 60 features not run: —."""
    from teamslam import api

    argv = ["paper", "fej", "--table", "1", "--runs", "2", "--features", "20"]
    assert main([*argv, "--workers", "1", "--json", "--data", str(shared_data)]) == 0
    records = _records(capsys)
    assert len(records) == 72
    folder = shared_data / "fej-environments"
    env = api.fej_environment(
        1, 20, [folder / "RobotsWaypoints_1.mat", folder / "CheckedTrueState_20features_1.mat"]
    )
    direct = api.fej_table(env, runs=2, workers=1).table
    cell = records["20 features Standard", "Robot 1 Pose NEES"]
    assert cell["paper"] == 2.1436 and cell["unit"] == "" and cell["table"] == "1"
    assert cell["ours"] == pytest.approx(direct["std"]["r1_pose_nees"], rel=1e-12)
    assert cell["difference"] == pytest.approx(cell["ours"] - cell["paper"])
    heading = records["20 features FEJ", "Robot 2 Heading RMSE"]
    assert heading["ours"] == pytest.approx(direct["fej"]["r2_heading_rmse"], rel=1e-12)
    assert heading["unit"] == "rad"
    for (row, _), r in records.items():
        if row.startswith("20 "):
            assert r["ours"] is not None and r["difference"] is not None
        else:
            assert r["ours"] is None and r["difference"] is None


def test_dvi_table_4_json_is_the_team_run(capsys):
    """Table IV on one tiny team: ours is `teamslam run --compare` of the same simulated team;
    the other team sizes are not run (—), and nothing claims a difference (our simulation)."""
    from teamslam import api
    from teamslam.sim import lissajous_team

    argv = ["paper", "dvi", "--table", "4", "--robots", "3", "--steps", "12", "--seeds", "1"]
    assert main([*argv, "--workers", "1", "--json"]) == 0
    records = _records(capsys)
    assert len(records) == 20
    run = api.run(lissajous_team(robots=3, steps=12, seed=0), mode="compare", progress=False)
    sep = records["Separate trajectory RMSE (m)", "3 robots"]
    assert sep["paper"] == 1.318
    assert sep["ours"] == pytest.approx(run.by_mode["separate"]["trajectory_rmse_avg_m"])
    con = records["Consensus object error (m)", "3 robots"]
    assert con["ours"] == pytest.approx(run.by_mode["consensus"]["object_error_avg_m"])
    time_cell = records["Consensus averaging time (s)", "3 robots"]
    assert time_cell["unit"] == "s" and 0 < time_cell["ours"] < 1
    for (_, column), r in records.items():
        assert r["difference"] is None
        assert (r["ours"] is None) == (column != "3 robots")


def test_dvi_table_1_on_kitti_head(kitti00_dir, capsys):
    """Table I on the first frames of KITTI 00: rows of 00 filled with ours − theirs, Avg and
    Max of ours over the robots; sequences without data —."""
    data = kitti00_dir.parents[1]
    argv = ["paper", "dvi", "--table", "1", "--frames", "25", "--workers", "1"]
    assert main([*argv, "--json", "--data", str(data)]) == 0
    records = _records(capsys)
    assert len(records) == 60
    for row in ("libviso2 [38]", "00 Separate", "00 Consensus"):
        robots = [records[row, f"Robot {k}"]["ours"] for k in (1, 2, 3)]
        assert all(v is not None and v >= 0 for v in robots)
        assert records[row, "Avg"]["ours"] == pytest.approx(np.mean(robots))
        assert records[row, "Max"]["ours"] == pytest.approx(np.max(robots))
        for r in (records[row, "Avg"], records[row, "Robot 2"]):
            assert r["difference"] == pytest.approx(r["ours"] - r["paper"])
    for (row, _), r in records.items():
        if row[:2] in ("05", "06", "08"):
            assert r["ours"] is None and r["paper"] is not None


def test_reproduce_all_writes_tables_figures_and_report(shared_data, tmp_path):
    settings = PaperSettings(fej_runs=2, fej_features=(20,), workers=1, progress=False)
    keys = ["fej-table-2", "fej-figure-5"]
    done, reproducer = reproduce_all(tmp_path, settings, shared_data, keys=keys)
    assert [d.key for d in done] == keys
    assert set(reproducer.seconds) == {"fej-env2"}  # one Monte Carlo for table and figure
    table = json.loads((tmp_path / "fej-table-2.json").read_text())
    assert len(table["cells"]) == 72
    md = (tmp_path / "fej-table-2.md").read_text()
    assert "| 20 features Standard | 2.6083 / " in md
    assert (tmp_path / "fej-figure-5.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (tmp_path / "report.html").read_text()
    assert "fej-table-2" in report and "data:image/png;base64," in report
    cells = json.loads((tmp_path / "paper.json").read_text())["cells"]
    assert len(cells) == 72
    # environment 2's 20 features run on the published files: ours − theirs on every run cell,
    # the file named in the table; the counts not run claim nothing
    assert "CheckedTrueState_20features_2.mat" in md
    for c in cells:
        assert (c["difference"] is not None) == c["row"].startswith("20 "), c


@pytest.mark.parametrize("env", [1, 2])
@pytest.mark.parametrize("count", [20, 60, 100])
def test_each_published_fej_environment_is_used(shared_data, env, count):
    """Every configuration of Tables 1 and 2 has its published pair of files, and the paper's
    command runs on it: the features and waypoints of the files, said so as the source."""
    import scipy.io

    from teamslam.paper.experiments import _fej_environment

    folder = shared_data / "fej-environments"
    environment, source, published = _fej_environment(env, count, shared_data)
    assert published and f"CheckedTrueState_{count}features_{env}.mat" in source
    lm = scipy.io.loadmat(folder / f"CheckedTrueState_{count}features_{env}.mat")["lm"]
    np.testing.assert_array_equal(environment.features, lm.T)
    waypoints = scipy.io.loadmat(folder / f"RobotsWaypoints_{env}.mat")
    assert [w.shape[0] for w in environment.waypoints] == [waypoints["wp1"].shape[1]] * 2
    generated, source, published = _fej_environment(env, count, None)
    assert not published and "generated" in source and generated.features.shape == (count, 2)


def test_missing_data_is_said_not_computed(tmp_path):
    result = Reproducer(PaperSettings(progress=False), tmp_path).build("dvi-table-2")
    assert all(c.ours is None for c in result.cells)
    assert any("not found" in line for line in result.setting)
    assert "8.76 / —" in result.text()


def test_cell_text_and_record():
    from teamslam.paper import Cell

    own = Cell("dvi", "I", "00 Separate", "Robot 3", "m", 12.65, 12.6499, 2, own_data=True)
    assert own.text() == "12.65 / 12.65 (+0.00)"
    assert own.record()["difference"] == pytest.approx(-1e-4)
    ours_only = Cell("dvi", "IV", "Separate object error (m)", "3 robots", "m", 1.402, 0.2, 3)
    assert ours_only.text() == "1.402 / 0.200" and ours_only.record()["difference"] is None
    missing = Cell("fej", "1", "60 features FEJ", "Robot 1 Pose NEES", "", 1.1143, None, 4, True)
    assert missing.text() == "1.1143 / —" and missing.record()["ours"] is None


def _computed_cells(out: Path) -> dict[tuple[str, str, str], dict]:
    """The cells of ``paper.json`` that are computed (the wall-clock times aside)."""
    cells = json.loads((out / "paper.json").read_text())["cells"]
    return {
        (c["table"], c["row"], c["column"]): c
        for c in cells
        if c["unit"] != "ms" and "time" not in c["row"]
    }


def test_reproduce_all_does_not_depend_on_the_workers(shared_data, tmp_path):
    """KITTI 00 (import, calibration, two filters), simulated teams, link loss and FEJ Monte
    Carlo in one pool: the same cells with one worker and with two, and the FEJ table the same
    numbers as the Monte Carlo run on its own (its runs are split over tasks)."""
    from teamslam import api

    keys = ["dvi-table-1", "dvi-table-4", "dvi-figure-4", "fej-table-1"]
    settings = {
        "team_sizes": (3,),
        "steps": 10,
        "loss_rates": (0.0, 0.5),
        "fej_runs": 7,
        "fej_features": (20,),
        "frames": 20,
        "progress": False,
    }
    cells = {}
    for workers in (1, 2):
        out = tmp_path / str(workers)
        _, reproducer = reproduce_all(
            out, PaperSettings.quick(workers=workers, **settings), shared_data, keys=keys
        )
        cells[workers] = _computed_cells(out)
        timing = reproducer.timing()
        assert timing["workers"] == workers
        assert timing["critical_path_seconds"] >= sum(reproducer.seconds.values()) / workers
    assert cells[1] == cells[2]
    filled = [c for c in cells[1].values() if c["ours"] is not None]
    assert len(filled) == 3 * 5 + 4 + 3 * 2 + 3 * 8
    # the link-loss run at r = 0 and the Table IV consensus run are the same run
    table4 = cells[1]["IV", "Consensus trajectory RMSE (m)", "3 robots"]["ours"]
    fig4 = cells[1]["Fig. 4", "3 robots, consensus, r = 0", "trajectory RMSE"]["ours"]
    assert fig4 == table4
    folder = shared_data / "fej-environments"
    env = api.fej_environment(
        1, 20, [folder / "RobotsWaypoints_1.mat", folder / "CheckedTrueState_20features_1.mat"]
    )
    direct = api.fej_table(env, runs=7, workers=1).table
    cell = cells[2]["1", "20 features FEJ", "Feature Position NEES"]
    assert cell["ours"] == direct["fej"]["feature_nees"]
