"""The ``teamslam`` command, one module per command group.

Exit status
-----------
0
    Success.
2
    The input is wrong: a flag, a value out of range, a setting, a malformed or inconsistent
    file (:class:`teamslam.errors.InputError`), an input file that cannot be read, or an
    optional extra the command needs that is not installed (the message names it).
1
    The inputs were valid but the run failed: the estimate could not be computed
    (:class:`teamslam.errors.EstimationError`, naming robot and frame), a result could not be
    written (:class:`teamslam.errors.OutputError` or a full or read-only disk, naming the
    path), a broken invariant of teamslam itself (:class:`teamslam.errors.InternalError`, a
    bug to report), or a robot process failed. Also, without a message, when standard output
    is a pipe whose reader has gone (``teamslam eval R | head``).
130
    Interrupted.

The command groups are imported when the parser is built, so ``teamslam --version`` loads none
of them.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import stat
import sys
from collections.abc import Sequence

from teamslam.cli._common import Parser
from teamslam.errors import (
    EXIT_FAILURE,
    EXIT_USAGE,
    EstimationError,
    InputError,
    InternalError,
    OutputError,
)

__all__ = ["EXIT_INTERRUPTED", "build_parser", "exit_status", "main"]

EXIT_INTERRUPTED = 130

# ros2 last: it adds options to run, data and agent
GROUPS = ("dvi", "data", "msckf", "team", "fej", "montecarlo", "evaluate", "paper", "ros2")

# an OSError with one of these numbers happened while writing, never while reading an input
_WRITE_ERRNOS = frozenset(
    getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EROFS", "EFBIG") if hasattr(errno, name)
)


def _version() -> str:
    from teamslam import __version__

    return f"teamslam {__version__}"


def build_parser() -> argparse.ArgumentParser:
    """The full ``teamslam`` argument parser (imports every command group)."""
    parser = Parser(
        prog="teamslam",
        description="Multi-robot SLAM by filtering: distributed inference, consistency measured.",
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for group in GROUPS:
        importlib.import_module(f"teamslam.cli.{group}").register(sub)
    return parser


def exit_status(exc: BaseException) -> tuple[int, str]:
    """The exit status of a command that raised ``exc`` and the word that introduces its message.

    Parameters
    ----------
    exc
        The exception a command handler raised.

    Returns
    -------
    (status, word)
        ``(2, "error")`` for a wrong input (:class:`InputError`, an input file that cannot be
        read); ``(1, "failed")`` for an estimation failure or a result that cannot be written;
        ``(1, "internal error")`` for a broken invariant of teamslam; ``(130, "interrupted")``.

    Raises
    ------
    TypeError
        If ``exc`` is none of the kinds a command reports (it is not caught: a traceback).
    """
    # order matters: OutputError is an OSError and a write failure, not a usage error
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED, "interrupted"
    if isinstance(exc, InternalError):
        return EXIT_FAILURE, "internal error"
    if isinstance(exc, EstimationError):
        return EXIT_FAILURE, "failed"
    if isinstance(exc, OutputError):
        return EXIT_FAILURE, "failed"
    if isinstance(exc, OSError) and exc.errno in _WRITE_ERRNOS:
        return EXIT_FAILURE, "failed"
    if isinstance(exc, (InputError, OSError)):
        return EXIT_USAGE, "error"
    raise TypeError(f"not a reported error: {type(exc).__name__}")


def _message(exc: BaseException, word: str) -> str:
    if word == "interrupted":
        return ""
    text = str(exc) or type(exc).__name__
    if word == "internal error":
        return f": {text} (a bug in teamslam: please report it with the command that was run)"
    return f": {text}"


def _stdout_is_pipe() -> bool:
    try:
        return stat.S_ISFIFO(os.fstat(sys.stdout.fileno()).st_mode)
    except (OSError, ValueError, AttributeError):
        return False


def _reader_gone() -> int:
    """Standard output is a pipe whose reader has gone (``teamslam eval R | head``): stop
    without a word. As Python's documentation recommends (``signal``, "Note on SIGPIPE"):
    standard output is pointed at ``/dev/null`` so that the flush at exit raises nothing, and
    the status is 1."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return EXIT_FAILURE


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``teamslam`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--version"]:  # answered without importing any command group
        sys.stdout.write(_version() + "\n")
        raise SystemExit(0)
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "handler", None) is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        status = int(args.handler(args))
        sys.stdout.flush()  # a reader that went away shows here, not at the interpreter's exit
        return status
    except BrokenPipeError:
        if not _stdout_is_pipe():
            raise
        return _reader_gone()
    except (InputError, EstimationError, InternalError, OSError, KeyboardInterrupt) as exc:
        status, word = exit_status(exc)
        sys.stderr.write(f"teamslam {args.command}: {word}{_message(exc, word)}\n")
        return status
