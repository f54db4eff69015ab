"""Small readers and formatters shared by the file formats and the command line."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

__all__ = ["format_value", "read_yaml", "yaml_problem"]


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
