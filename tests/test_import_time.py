"""Importing teamslam is cheap: names load on first use (PEP 562), the CLI's groups on parsing.

Each check runs in a fresh interpreter and looks at ``sys.modules``: what was loaded, not how
long it took.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import teamslam

_SRC = str(Path(teamslam.__file__).resolve().parents[1])
_HEAVY = ("numpy", "scipy", "matplotlib", "numba", "zenoh", "yaml", "rosbags")


def _loaded_after(code: str) -> dict:
    """Run ``code`` in a fresh interpreter; the modules it left loaded and what it printed."""
    script = f"import sys, json\n{code}\nprint(json.dumps(sorted(sys.modules)))\n"
    env = {**os.environ, "PYTHONPATH": _SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    *printed, modules = proc.stdout.strip().splitlines()
    return {"modules": set(json.loads(modules)), "printed": printed}


def _heavy(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] in _HEAVY)


@pytest.mark.parametrize("code", ["import teamslam.errors", "import teamslam"])
def test_importing_the_package_or_its_errors_loads_no_numerical_library(code):
    modules = _loaded_after(code)["modules"]
    assert _heavy(modules) == []
    ours = sorted(m for m in modules if m.startswith("teamslam"))
    assert set(ours) <= {"teamslam", "teamslam._lazy", "teamslam._version", "teamslam.errors"}, ours


def test_version_on_the_command_line_imports_no_command_group():
    result = _loaded_after(
        "from teamslam.cli import main\n"
        "try:\n"
        "    main(['--version'])\n"
        "except SystemExit as exc:\n"
        "    assert exc.code == 0, exc.code"
    )
    assert result["printed"] == [f"teamslam {teamslam.__version__}"]
    assert _heavy(result["modules"]) == []
    assert not any(
        m.startswith("teamslam.cli.") and m != "teamslam.cli._common" for m in result["modules"]
    )


def test_public_names_resolve_on_first_access_to_the_defining_objects():
    from teamslam.msckf.settings.values import MsckfConfig
    from teamslam.msckf.team import run_team

    result = _loaded_after(
        "import teamslam\n"
        "print('numpy' in sys.modules)\n"
        "config = teamslam.MsckfConfig\n"
        "print('numpy' in sys.modules, config.__module__, config.__qualname__)\n"
        "print(teamslam.run_team.__module__, teamslam.run_team.__qualname__)\n"
        "print(teamslam.datasets.__name__, teamslam.sim.lissajous_team.__module__)\n"
        "print(teamslam.geometry.se3.__name__, teamslam.msckf.filter.state.__name__)"
    )
    assert result["printed"] == [
        "False",
        f"True {MsckfConfig.__module__} {MsckfConfig.__qualname__}",
        f"{run_team.__module__} {run_team.__qualname__}",
        "teamslam.datasets teamslam.sim.lissajous",
        "teamslam.geometry.se3 teamslam.msckf.filter.state",
    ]


def _declared_origins(package) -> dict[str, str]:
    """``{name: defining module}`` from the package's ``if TYPE_CHECKING:`` imports."""
    import ast

    origins = {}
    tree = ast.parse(Path(package.__file__).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module != package.__name__:
            origins.update({alias.name: node.module for alias in node.names})
    return origins


SUBPACKAGES = (
    "teamslam.datasets",
    "teamslam.dvi",
    "teamslam.ekf2d",
    "teamslam.geometry",
    "teamslam.msckf",
    "teamslam.runtime",
    "teamslam.sim",
)


def test_every_exported_name_is_the_defining_object_even_after_its_submodule_is_imported():
    import importlib
    import pkgutil

    for name in SUBPACKAGES:
        package = importlib.import_module(name)
        origins = _declared_origins(package)
        assert set(package.__all__) <= set(origins) | {
            m.name for m in pkgutil.iter_modules(package.__path__)
        }
        # importing every submodule must not replace a name by a module of the same name
        for info in pkgutil.iter_modules(package.__path__):
            importlib.import_module(f"{name}.{info.name}")
        for exported in package.__all__:
            value = getattr(package, exported)
            if exported in origins and origins[exported] != "typing":
                expected = getattr(importlib.import_module(origins[exported]), exported)
                assert value is expected, (name, exported, value)
            assert exported in dir(package), (name, exported)
    import teamslam.dvi

    assert callable(teamslam.dvi.mirror_descent)  # the function, not the module of that name
    for exported in set(teamslam.__all__) - {"run", "write_run", "load_run"}:
        assert getattr(teamslam, exported) is not None
        assert exported in dir(teamslam)
    assert (
        teamslam.MsckfConfig
        is importlib.import_module("teamslam.msckf.settings.values").MsckfConfig
    )
    assert {"run", "write_run", "load_run"} <= set(dir(teamslam))


def test_unknown_names_are_attribute_errors():
    with pytest.raises(AttributeError, match="no attribute 'no_such_thing'"):
        _ = teamslam.no_such_thing
    with pytest.raises(AttributeError, match=r"'teamslam\.msckf'"):
        _ = teamslam.msckf.no_such_thing
    assert not hasattr(teamslam.sim, "no_such_thing")


def test_a_missing_defining_module_is_an_attribute_error_but_a_missing_dependency_is_not(
    tmp_path, monkeypatch
):
    from teamslam._lazy import attach

    (tmp_path / "needs_missing.py").write_text("import teamslam_no_such_dependency\nvalue = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    getattr_, _ = attach(
        "teamslam",
        (),
        {"value": "needs_missing", "absent": "teamslam.no_such_module"},
    )
    with pytest.raises(AttributeError, match=r"teamslam\.no_such_module is not available"):
        getattr_("absent")
    with pytest.raises(ModuleNotFoundError, match="teamslam_no_such_dependency"):
        getattr_("value")


def test_the_installed_metadata_carries_the_package_version():
    from importlib.metadata import PackageNotFoundError, version

    try:
        installed = version("teamslam")
    except PackageNotFoundError:
        pytest.skip("teamslam is not installed (running from a source tree)")
    assert installed == teamslam.__version__
