"""The optional extras: without one, a command that needs it exits 2 naming the extra; a run
over a dataset in one process needs none of them.

Each command runs in a fresh interpreter whose ``sitecustomize`` makes the extra's modules
unimportable (``sys.modules[name] = None``, as for a package that is not installed); robot
processes it would start inherit the same block.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

import teamslam
from teamslam._optional import EXTRAS, MissingExtra, require
from teamslam.errors import InputError

_SRC = Path(teamslam.__file__).resolve().parents[1]
_ROOT = _SRC.parent
EVERY_EXTRA_MODULE = tuple(m for modules in EXTRAS.values() for m in modules)


def _teamslam(argv: list[str], blocked: tuple[str, ...], tmp: Path, code: str | None = None):
    """``teamslam ARGV`` (or python ``code``) in a fresh interpreter without ``blocked``."""
    site = tmp / f"site-{'-'.join(blocked) or 'none'}"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(
        "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in blocked)
    )
    path = os.pathsep.join([str(site), str(_SRC), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path, "OPENBLAS_NUM_THREADS": "1"}
    command = ["-c", code] if code is not None else ["-m", "teamslam", *argv]
    return subprocess.run(
        [sys.executable, *command], capture_output=True, text=True, env=env, timeout=600, cwd=tmp
    )


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A small dataset, its team file, and a run of it made with no extra installed."""
    from teamslam.datasets import save_dataset
    from teamslam.graph import make
    from teamslam.runtime.team_file import write_team_file
    from teamslam.sim import lissajous_team

    tmp = tmp_path_factory.mktemp("extras")
    dataset = save_dataset(lissajous_team(robots=2, steps=12, seed=0), tmp / "team2")
    team = write_team_file(tmp / "team.yaml", "extras", dataset, make("complete", 2).adjacency)
    done = _teamslam(["run", str(dataset), "--out", str(tmp / "run")], EVERY_EXTRA_MODULE, tmp)
    return {"tmp": tmp, "dataset": dataset, "team": team, "run": done}


def test_importing_and_running_a_dataset_need_no_extra(workspace):
    done = workspace["run"]
    assert done.returncode == 0, done.stderr
    run = workspace["tmp"] / "run"
    assert (run / "metrics.json").is_file() and (run / "report.html").is_file()
    loaded = teamslam.load_run(run)
    assert loaded.metrics["trajectory_rmse_avg_m"] >= 0
    # every command group loads, and the library's names resolve, without any extra
    code = (
        "import teamslam, teamslam.api, teamslam.cli\n"
        "teamslam.cli.build_parser()\n"
        "assert callable(teamslam.run) and callable(teamslam.load_run)\n"
    )
    done = _teamslam([], EVERY_EXTRA_MODULE, workspace["tmp"], code=code)
    assert done.returncode == 0, done.stderr


def _commands(w):
    tmp, dataset, team = w["tmp"], str(w["dataset"]), str(w["team"])
    return {
        "run --processes": (
            ("zenoh",),
            ["run", dataset, "--processes", "--out", f"{tmp}/p"],
            "network",
            "running robots as processes",
        ),
        "run --processes --secure": (
            ("cryptography",),
            ["run", dataset, "--processes", "--secure", "--out", f"{tmp}/s"],
            "network",
            "a secured team",
        ),
        "team launch": (("zenoh",), ["team", "launch", team, "--out", f"{tmp}/l"], "network", None),
        "agent": (
            ("zenoh",),
            ["agent", "--team", team, "--robot", "0", "--out", f"{tmp}/a"],
            "network",
            None,
        ),
        "team certs": (
            ("cryptography",),
            ["team", "certs", team, "--out", f"{tmp}/certs"],
            "network",
            None,
        ),
        "run --mcap": (
            ("rosbags",),
            ["run", dataset, "--out", f"{tmp}/m", "--mcap"],
            "ros2",
            "MCAP output",
        ),
        "export mcap": (
            ("rosbags",),
            ["export", "mcap", str(tmp / "run"), "--out", f"{tmp}/x/run.mcap"],
            "ros2",
            None,
        ),
        "data export-bag": (
            ("rosbags",),
            ["data", "export-bag", dataset, "--out", f"{tmp}/e/team.mcap"],
            "ros2",
            "writing a ROS 2 bag",
        ),
        "data import-bag": (
            ("rosbags",),
            [
                *("data", "import-bag", f"{tmp}/e/team.mcap", "--robot", "a:/a/odom"),
                *("--observations", "/{name}/obs", "--camera", "camera.yaml", "--out", f"{tmp}/i"),
            ],
            "ros2",
            "reading a ROS 2 bag",
        ),
        "agent --ros2": (
            ("xxhash",),
            ["agent", "--team", team, "--robot", "0", "--out", f"{tmp}/r", "--ros2"],
            "ros2",
            "publishing ROS 2 topics",
        ),
        "agent --foxglove": (
            ("foxglove",),
            ["agent", "--team", team, "--robot", "0", "--out", f"{tmp}/fg", "--foxglove", "0"],
            "foxglove",
            "a Foxglove live view (--foxglove)",
        ),
        "simulate --images": (
            ("cv2",),
            ["simulate", "--images", "--robots", "1", "--steps", "2", "--out", f"{tmp}/im"],
            "images",
            "rendering images",
        ),
        "data from-images": (
            ("cv2",),
            ["data", "from-images", "--rendered", f"{tmp}/im", "--out", f"{tmp}/fi"],
            "images",
            None,
        ),
        "montecarlo --scheduler": (
            ("distributed",),
            [
                *("montecarlo", "--robots", "1", "--steps", "2", "--runs", "1"),
                *("--scheduler", "tcp://127.0.0.1:8786", "--out", f"{tmp}/mc"),
            ],
            "cluster",
            "running on a Dask cluster",
        ),
        "paper --scheduler": (
            ("distributed",),
            [
                *("paper", "all", "--only", "dvi-table-4", "--quick", "--robots", "2"),
                *("--scheduler", "tcp://127.0.0.1:8786", "--out", f"{tmp}/pa"),
            ],
            "cluster",
            "running on a Dask cluster",
        ),
    }


COMMANDS = [
    "run --processes",
    "run --processes --secure",
    "team launch",
    "agent",
    "team certs",
    "run --mcap",
    "export mcap",
    "data export-bag",
    "data import-bag",
    "agent --ros2",
    "agent --foxglove",
    "simulate --images",
    "data from-images",
    "montecarlo --scheduler",
    "paper --scheduler",
]


@pytest.mark.parametrize("name", COMMANDS)
def test_a_command_without_its_extra_exits_2_naming_it(workspace, name):
    blocked, argv, extra, what = _commands(workspace)[name]
    assert workspace["run"].returncode == 0  # the export reads that run
    done = _teamslam(argv, blocked, workspace["tmp"])
    assert done.returncode == 2, (done.stdout, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert lines[0].endswith(f"needs the '{extra}' extra: pip install 'teamslam[{extra}]'")
    assert lines[0].startswith(f"teamslam {argv[0]}: error: ")
    if what is not None:
        assert f": error: {what} needs" in lines[0]
    # nothing was written where the command would have put its results
    out = Path(argv[argv.index("--out") + 1])
    assert not out.exists() or not any(out.iterdir()), sorted(out.iterdir())


def test_every_command_of_the_list_is_tested(workspace):
    assert set(_commands(workspace)) == set(COMMANDS)
    assert {extra for _, _, extra, _ in _commands(workspace).values()} == set(EXTRAS)


def test_require_returns_the_module_or_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "zenoh", None)
    with pytest.raises(MissingExtra) as caught:
        require("zenoh.ext", "network", "the thing")
    assert isinstance(caught.value, InputError)
    assert (
        str(caught.value) == "the thing needs the 'network' extra: pip install 'teamslam[network]'"
    )
    pytest.importorskip("cryptography")
    x509 = require("cryptography.x509", "network", "certificates")
    assert x509.__name__ == "cryptography.x509" and hasattr(x509, "load_pem_x509_certificate")


def test_a_module_that_is_present_but_broken_is_named_with_its_reason(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def broken(name, *args, **kwargs):
        if name == "cv2":
            raise ImportError("libGL.so.1: cannot open shared object file")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", broken)
    with pytest.raises(MissingExtra, match=r"\(cv2 does not import: libGL\.so\.1: cannot open"):
        require("cv2", "images", "the image front-end")


def test_a_module_of_no_extra_is_a_bug_of_the_caller():
    from teamslam.errors import InternalError

    with pytest.raises(InternalError, match="json"):
        require("json", "network", "x")


def _imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def test_every_import_of_an_extra_goes_through_require():
    wrong = []
    for path in sorted((_SRC / "teamslam").rglob("*.py")):
        for name in _imported_modules(path):
            if name.split(".")[0] in EVERY_EXTRA_MODULE:
                wrong.append(f"{path.relative_to(_SRC)} imports {name}")
    assert not wrong, wrong


def _requirement_name(requirement: str) -> str:
    from packaging.requirements import Requirement

    return Requirement(requirement).name.lower().replace("_", "-")


def test_each_extra_installs_the_distributions_of_its_modules_and_the_core_none():
    project = tomllib.loads((_ROOT / "pyproject.toml").read_text())["project"]
    optional = project["optional-dependencies"]
    core = {_requirement_name(r) for r in project["dependencies"]}
    providers = packages_distributions()
    checked = 0
    for extra, modules in EXTRAS.items():
        listed = {_requirement_name(r) for r in optional[extra]}
        for module in modules:
            distributions = {d.lower().replace("_", "-") for d in providers.get(module, ())}
            if not distributions:
                continue  # not installed here: nothing to compare
            assert distributions & listed, (extra, module, distributions, listed)
            assert not distributions & core, (module, distributions)
            checked += 1
    assert checked, "no extra installed: nothing checked"
    assert optional["all"] == [f"teamslam[{','.join(EXTRAS)}]"]
