"""Names of a package resolved on first access (PEP 562), so that importing it stays cheap.

A package lists its submodules and the names it re-exports; :func:`attach` returns the
module-level ``__getattr__`` and ``__dir__`` that import a submodule the first time one of its
names is used. ``import teamslam.errors`` then loads no numerical library, and
``teamslam --version`` answers without importing the filters.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable, Mapping

__all__ = ["attach"]


def attach(
    package: str,
    submodules: Iterable[str] = (),
    names: Mapping[str, str] | None = None,
) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package``.

    Parameters
    ----------
    package
        The package's ``__name__``.
    submodules
        Submodules reached as attributes (``teamslam.msckf``), imported on first access.
    names
        Re-exported names and the module that defines each (``{"run_team":
        "teamslam.msckf.team"}``); a name is imported from its module on first access and then
        kept in the package's namespace. A name that is also a submodule's is imported at
        once.

    Returns
    -------
    (getattr, dir)
        To be bound as ``__getattr__`` and ``__dir__`` in the package's ``__init__``.
    """
    submodules = frozenset(submodules)
    names = dict(names or {})
    for name in sorted(submodules & names.keys()):
        # A name that is also a submodule's (``dvi.mirror_descent``, the function, in the
        # module ``dvi/mirror_descent.py``) would be replaced by the module the moment anything
        # imports that submodule, so it is bound now, as an eager import would.
        value = getattr(importlib.import_module(names[name]), name)
        setattr(sys.modules[package], name, value)

    def __getattr__(name: str) -> object:
        if name in submodules:
            return importlib.import_module(f"{package}.{name}")
        module_name = names.get(name)
        if module_name is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            raise AttributeError(
                f"module {package!r} has no attribute {name!r} ({module_name} is not available)"
            ) from exc
        value = getattr(module, name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | submodules | set(names))

    return __getattr__, __dir__
