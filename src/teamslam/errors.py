"""The two kinds of failure teamslam reports, and the exit codes the command line gives them.

* :class:`InputError` — something the user gave is wrong: a command-line value, a malformed or
  inconsistent file, a message from the network that cannot be decoded. The text names what was
  wrong. ``teamslam`` exits with status 2.
* :class:`EstimationError` — the inputs were valid but the estimate could not be computed (a
  covariance that lost positive definiteness, a diverging filter). The text names the robot and
  the frame where known. ``teamslam`` exits with status 1.

Every error of the package derives from one of the two, so callers can tell "fix your input"
from "the filter failed" without parsing messages.
"""

from __future__ import annotations

__all__ = [
    "EXIT_FAILURE",
    "EXIT_USAGE",
    "EstimationError",
    "InputError",
    "InternalError",
    "OutputError",
]

EXIT_USAGE = 2
EXIT_FAILURE = 1


class InputError(ValueError):
    """Bad input: a value, a file or a message that cannot be used; the text names it."""


class EstimationError(ArithmeticError):
    """A numerical failure of an estimator on valid input; the text names robot and frame."""


class InternalError(RuntimeError):
    """A broken invariant of teamslam itself (a bug): the text says which; please report it."""


class OutputError(OSError):
    """A result could not be written; the text names the path (exit 1, not a usage error)."""
