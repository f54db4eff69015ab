"""The documentation site: its examples run, its commands are valid, its generated reference
pages follow the code, and the built site renders in a real browser.

The site is built once for the module with ``mkdocs build --strict`` (a broken link, a missing
page or an unresolved reference fails) and served on loopback for headless Chromium.
"""

from __future__ import annotations

import dataclasses
import functools
import http.server
import importlib.util
import math
import os
import re
import runpy
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from test_readme import check_teamslam_command, code_blocks, shell_commands

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
NO_DOCS_EXTRA = "the docs extra is not installed (pip install -e '.[docs]')"


def _hooks():
    """The build-time generator (``docs/hooks/reference.py``), imported from its file."""
    pytest.importorskip(
        "griffe", reason="the docs extra is not installed (pip install -e '.[docs]')"
    )
    spec = importlib.util.spec_from_file_location("docs_reference", DOCS / "hooks" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while they are built
    spec.loader.exec_module(module)
    return module


hooks = functools.cache(_hooks)


def _nav_pages(nav) -> list[str]:
    pages = []
    for entry in nav:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        pages.extend(_nav_pages(value) if isinstance(value, list) else [value])
    return pages


def _mkdocs_config() -> dict:
    import yaml

    return yaml.safe_load((ROOT / "mkdocs.yml").read_text())


# --------------------------------------------------------------------------------------------
# the examples the pages include


def test_dataset_example_writes_a_dataset_that_loads_and_runs(tmp_path, capsys):
    from teamslam.api import run
    from teamslam.cli import main
    from teamslam.datasets import load_dataset

    out = tmp_path / "two-robots"
    subprocess.run(
        [sys.executable, str(DOCS / "reference" / "dataset_example.py"), str(out)], check=True
    )
    dataset = load_dataset(out)
    assert dataset.n_robots == 2
    assert dataset.sensor_model is not None and dataset.sensor_model.origin == "user"
    assert [r.frames for r in dataset.robots] == [12, 12]
    assert all(r.objects.ids.size > 0 and r.features.ids.size == 0 for r in dataset.robots)

    capsys.readouterr()
    assert main(["data", "info", str(out), "--json"]) == 0
    assert '"robots": 2' in capsys.readouterr().out

    result = run(out, mode="compare")
    separate, consensus = result.by_mode["separate"], result.by_mode["consensus"]
    for metrics in (separate, consensus):
        assert math.isfinite(metrics["trajectory_rmse_avg_m"])
    # two robots that see the same objects agree on them far better with consensus
    assert consensus["object_disagreement_avg_m"] < 0.5 * separate["object_disagreement_avg_m"]


def test_api_example_runs(capsys):
    namespace = runpy.run_path(str(DOCS / "reference" / "api_example.py"), run_name="__main__")
    assert len(namespace["run"].means) == 4  # the distributed filter's agents
    separate, consensus = namespace["results"][False], namespace["results"][True]
    assert len(separate.poses) == len(consensus.poses) == 3
    printed = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in printed] == ["False", "True"]


def test_wire_example_runs():
    runpy.run_path(str(DOCS / "reference" / "wire_example.py"), run_name="__main__")


def test_team_file_example_loads():
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(DOCS / "reference" / "team_example.yaml")
    assert team.n == 3
    assert all(r.id in team.robots[j].neighbours for r in team.robots for j in r.neighbours)


def test_included_files_exist():
    """Every ``--8<--`` include of a page names a file (the strict build checks it too)."""
    pages = list(DOCS.rglob("*.md"))
    includes = [
        (page, name)
        for page in pages
        for name in re.findall(r'^--8<-- "([^"]+)"', page.read_text(), re.M)
    ]
    assert includes
    for page, name in includes:  # snippets' base paths: docs/, then the repository root
        found = (DOCS / name).is_file() or (ROOT / name).is_file()
        assert found, f"{page.relative_to(ROOT)} includes missing {name}"


# --------------------------------------------------------------------------------------------
# the commands the pages show


def test_every_command_on_the_pages_parses():
    commands = []
    for page in sorted(DOCS.rglob("*.md")):
        text = page.read_text()
        for block in code_blocks(text, "sh"):
            commands += [(page, argv) for argv in shell_commands(block, "teamslam")]
    assert len(commands) > 40
    for page, argv in commands:
        check_teamslam_command(argv, str(page.relative_to(ROOT)))


def test_a_wrong_command_is_caught():
    with pytest.raises(pytest.fail.Exception):
        check_teamslam_command(["run", "results/x", "--no-such-flag"], "here")
    with pytest.raises(Exception, match="unknown setting"):
        check_teamslam_command(["run", "results/x", "--set", "no_such_setting=1"], "here")


def test_nav_lists_every_page_and_every_page_exists():
    nav = _nav_pages(_mkdocs_config()["nav"])
    for page in nav:
        assert (DOCS / page).is_file(), f"mkdocs.yml names missing page {page}"
    pages = {  # the generated tables are included by the results pages, not pages of their own
        str(p.relative_to(DOCS))
        for p in DOCS.rglob("*.md")
        if "hooks" not in p.relative_to(DOCS).parts
        and p.relative_to(DOCS).parts[:2] != ("results", "generated")
    }
    assert pages == set(nav), f"pages not in the navigation: {sorted(pages - set(nav))}"


# --------------------------------------------------------------------------------------------
# the generated reference


def test_settings_reference_lists_every_field_with_its_description():
    from teamslam.association import AssociationSettings
    from teamslam.msckf.settings.values import MsckfConfig

    for cls in (MsckfConfig, AssociationSettings):
        settings = hooks().settings_of(cls)
        leaves = [s for s in settings if not s.group]
        assert leaves, cls
        assert all(s.description for s in settings), [s.name for s in settings if not s.description]
        defaults = {s.name: s.default for s in leaves}
        instance = cls()
        for name, default in defaults.items():
            value = functools.reduce(getattr, name.split("."), instance)
            if isinstance(value, bool):
                assert default == str(value).lower()
            elif isinstance(value, float) and math.isinf(value):
                assert default == "inf"
            else:
                assert default == (value if isinstance(value, str) else repr(value))


@dataclasses.dataclass(frozen=True)
class _Gate:
    """The gate.

    Attributes
    ----------
    probability
        Gate probability (:data:`~teamslam.gaussian.chi2_quantile`).
    """

    probability: float = 0.99


@dataclasses.dataclass(frozen=True)
class _Tracking:
    """Tracking.

    Attributes
    ----------
    gate
        How detections are gated.
    confirm_hits, confirm_frames
        M of N confirmation.
    """

    gate: _Gate = dataclasses.field(default_factory=_Gate)
    confirm_hits: int = 0
    confirm_frames: int = 0


@dataclasses.dataclass(frozen=True)
class _Nested:
    """Settings in groups.

    Attributes
    ----------
    window
        Window size.
    tracking
        Tracking settings.
    """

    window: int = 20
    tracking: _Tracking = dataclasses.field(default_factory=_Tracking)


def test_settings_generator_walks_nested_groups():
    settings = {s.name: s for s in hooks().settings_of(_Nested)}
    assert list(settings) == [
        "window",
        "tracking",
        "tracking.gate",
        "tracking.gate.probability",
        "tracking.confirm_hits",
        "tracking.confirm_frames",
    ]
    assert settings["tracking"].group and settings["tracking.gate"].group
    assert settings["tracking.gate.probability"].default == "0.99"
    assert settings["tracking.gate.probability"].description == (
        "Gate probability (`chi2_quantile`)."
    )
    assert settings["tracking.confirm_frames"].description == "M of N confirmation."
    markdown = hooks().settings_markdown(_Nested)
    assert "#### `tracking.confirm_hits`" in markdown and "##### `tracking.gate.probability`" in (
        markdown
    )


def test_cli_reference_has_every_command():
    from teamslam.cli import build_parser

    markdown = hooks().cli_markdown(build_parser())
    commands = [" ".join(path) for path, _, _ in hooks()._walk(build_parser())]
    assert {"run", "data info", "team launch", "paper all", "export mcap"} <= set(commands)
    for command in commands:
        assert f"## `teamslam {command}`" in markdown
        assert f"usage: teamslam {command}" in markdown


def test_roles_become_code():
    roles = hooks().roles_as_code
    assert roles(":func:`~teamslam.api.run` and :mod:`teamslam.gaussian`") == (
        "`run` and `teamslam.gaussian`"
    )
    assert roles(":class:`the run <teamslam.api.Run>`") == "`the run`"


# --------------------------------------------------------------------------------------------
# the built site


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip(
        "mkdocs", reason="the docs extra is not installed (pip install -e '.[docs]')"
    )
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**env, "NO_MKDOCS_2_WARNING": "1"},
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    return out


@pytest.fixture(scope="module")
def served(site):
    """The built site on an ephemeral loopback port."""
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))

    class Quiet(handler.func):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(Quiet, **handler.keywords)
    )
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_site_is_self_contained(site):
    """Nothing is fetched from elsewhere: no stylesheet, script or font from another host."""
    for page in site.rglob("*.html"):
        text = page.read_text()
        external = re.findall(r'<(?:link|script)[^>]+(?:href|src)="(https?://[^"]+)"', text)
        assert not external, f"{page.relative_to(site)} fetches {external}"
    assert (site / "assets" / "report.png").is_file()
    assert (site / "reference" / "dataset_example.py").is_file()


def test_site_renders_in_headless_chromium(served, chromium, tmp_path):
    import numpy as np
    from matplotlib.image import imread

    home = chromium("--dump-dom", f"{served}/index.html")
    assert home.returncode == 0, home.stderr[-2000:]
    dom = home.stdout
    assert "<title>teamslam</title>" in dom
    # the navigation, rendered by the theme's templates
    nav = dom[dom.index('<nav class="md-nav md-nav--primary"') :]
    for entry in ("Getting started", "Your own data", "Dataset format", "Settings", "Python API"):
        assert entry in nav, entry
    assert 'src="assets/report.png"' in dom

    settings = chromium("--dump-dom", f"{served}/reference/settings.html").stdout
    assert 'id="filterwindow"' in settings and "Window size" in settings
    assert 'id="consensuskl_threshold"' in settings
    api = chromium("--dump-dom", f"{served}/reference/api.html").stdout
    assert 'id="teamslam.api.run"' in api and "Run the filter over a team dataset" in api
    assert ":func:" not in api and ":class:" not in api

    shot = tmp_path / "home.png"
    done = chromium(f"--screenshot={shot}", f"{served}/index.html")
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    rgb = (imread(shot)[..., :3] * 255).round().astype(int)
    assert rgb.shape[:2] == (1400, 1280)
    # the theme's stylesheet was applied: the header bar across the top is indigo, not white
    header = rgb[10:40, 200:1000].reshape(-1, 3)
    assert np.median(header, axis=0).tolist() == pytest.approx([63, 81, 181], abs=12)
