"""Small readers and formatters shared by the file formats and the command line."""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

if TYPE_CHECKING:
    import numpy as np

__all__ = ["format_value", "open_npz", "read_npz", "read_yaml", "yaml_problem"]

# numpy parses each array's header with ast.literal_eval, and CPython (3.11 at least) counts the
# AST constructor's recursion depth in state its threads share: two threads parsing at once
# (robots' drivers in threads of one process, each loading its data) can fail with
# "SystemError: AST constructor recursion depth mismatch". Archives are read one at a time.
_NPZ_READ = threading.RLock()


@contextmanager
def open_npz(path: str | Path) -> Iterator[Any]:
    """An ``.npz`` archive opened with pickle disabled, read inside the block by one thread.

    Every archive of the library is read through here (or :func:`read_npz`), under one
    process-wide lock, so threads of one process may load datasets, checkpoints and results at
    once. Errors are numpy's (``OSError``, ``ValueError``, ``zipfile.BadZipFile``); the caller
    names the file.
    """
    import numpy as np

    with _NPZ_READ, np.load(path, allow_pickle=False) as npz:
        yield npz


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive by name, read as :func:`open_npz` reads."""
    with open_npz(path) as npz:
        return {name: npz[name] for name in npz.files}


def read_yaml(path: str | Path, error: type[Exception]) -> Any:
    """Parse a YAML file; an unreadable file or bad YAML raises ``error`` naming the file."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {yaml_problem(exc)}") from None


def yaml_problem(exc: Exception) -> str:
    """A YAML parser's error on one line: where (line and column, counted from 1), what."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if problem is None:
        return " ".join(str(exc).split())
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    context, context_mark = getattr(exc, "context", None), getattr(exc, "context_mark", None)
    if not context:
        return f"{where}{problem}"
    if context_mark is not None and context_mark is not mark:
        context += f" at line {context_mark.line + 1}, column {context_mark.column + 1}"
    return f"{where}{problem} ({context})"


def format_value(value: Any, digits: int = 4) -> str:
    """A number or a sequence of numbers with ``digits`` significant digits; ``—`` for None."""
    if value is None:
        return "—"
    if isinstance(value, Sequence) and not isinstance(value, str):
        return "[" + ", ".join(f"{v:.{digits}g}" for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)
