"""What every command group shares: the parser class, argument types and the filter settings."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

from teamslam.errors import InputError

__all__ = [
    "Parser",
    "UsageError",
    "ctrl_c_interrupts",
    "default_data",
    "effective_settings",
    "non_negative_float",
    "non_negative_int",
    "number",
    "positive_float",
    "positive_int",
    "print_health",
    "print_mcap_summary",
    "print_run",
    "rate",
    "ros_domain_id",
    "save_and_describe",
    "settings_arguments",
    "settings_line",
]


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


class UsageError(InputError):
    """A command-line value that parses but cannot be used."""


@contextlib.contextmanager
def ctrl_c_interrupts() -> Iterator[None]:
    """While the block runs, SIGINT (Ctrl-C, ``kill -INT``, a launcher's shutdown) raises
    KeyboardInterrupt in the main thread, whatever the process inherited.

    A process started with SIGINT ignored — a job a shell without job control put in the
    background (``cmd &`` in a script), or a launcher that ignores it in its children — or with
    SIGINT in its signal mask never sees it: Python installs its KeyboardInterrupt handler only
    when SIGINT is not ignored, and a blocked signal stays pending. The commands that run until
    stopped (``bag play --loop``, ``agent``, ``team launch``) run in this block. The handler is
    set (when SIGINT was ignored or at the system default) and SIGINT unblocked in the calling
    thread only for the block; both are restored after it. Outside the main thread, where
    Python runs no signal handler, nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = signal.getsignal(signal.SIGINT)
    replace = handler in (signal.SIG_IGN, signal.SIG_DFL)
    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    if replace:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if blocked:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
    try:
        yield
    finally:
        if blocked:
            signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])
        if replace:
            signal.signal(signal.SIGINT, handler)


def number(kind: type, accept, expected: str):
    """An argparse type: ``kind(text)`` for which ``accept(value)`` holds, else a one-line
    error "expected <expected>, got …"."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not (math.isfinite(value) and accept(value)):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {value}")
        return value

    return parse


positive_int = number(int, lambda v: v >= 1, "a positive integer")
non_negative_int = number(int, lambda v: v >= 0, "an integer ≥ 0")
rate = number(float, lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
positive_float = number(float, lambda v: v > 0, "a positive number")
non_negative_float = number(float, lambda v: v >= 0, "a number ≥ 0")
ros_domain_id = number(int, lambda v: 0 <= v <= 232, "a ROS domain id in 0..232")


def save_and_describe(dataset, out: Path) -> Path:
    """Save ``dataset`` to ``out``, print its summary and where it went; the saved path."""
    from teamslam.datasets import dataset_info, format_info, save_dataset

    path = save_dataset(dataset, out)
    print(format_info(dataset_info(dataset)))
    print(f"\nwrote {path}")
    return path


def default_data() -> Path:
    """``$TEAMSLAM_DATA`` or ``../shared/data`` relative to the working directory."""
    return Path(os.environ.get("TEAMSLAM_DATA", Path("..") / "shared" / "data"))


def settings_arguments(parser: argparse.ArgumentParser, calibration_flags: bool = True) -> None:
    """``--config`` and ``--set`` (and, unless told otherwise, when to calibrate)."""
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="YAML file of filter settings (group: {name: value} or group.name: value)",
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="GROUP.NAME=VALUE",
        help="a filter setting, e.g. --set filter.object_std=0.01 (repeatable; wins over "
        "--config; `teamslam config show DATASET` lists them)",
    )
    if not calibration_flags:
        return
    parser.add_argument(
        "--calibrate",
        choices=("auto", "always", "never"),
        default="auto",
        help="calibrate noise levels from the data: when the dataset, file and flags lack them "
        "(auto), in place of the dataset's (always), or not at all (never)",
    )
    parser.add_argument(
        "--calibration-frames",
        type=positive_int,
        default=None,
        help="frames per robot a calibration uses (default: ~1200/robots)",
    )


def effective_settings(args: argparse.Namespace, dataset, calibrate: str | None = None):
    """The effective settings of a run: dataset, calibration, ``--config``, flags."""
    from teamslam.msckf.configure import build_settings

    flags = list(args.set or [])
    if getattr(args, "window", None):
        flags.append(f"filter.window={args.window}")
    if getattr(args, "objects_only", False):
        flags.append("filter.use_geometric_features=false")
    return build_settings(
        dataset,
        args.config,
        flags,
        calibrate=calibrate or args.calibrate,
        calibration_frames=getattr(args, "calibration_frames", None),
    )


def settings_line(dataset, effective) -> str:
    """One line: where the noise levels came from."""
    model = dataset.sensor_model
    if effective.calibration is not None:
        c = effective.calibration
        keys = sorted(k for k, v in effective.sources.items() if v == "calibration")
        return (
            f"sensor model: {'none in the dataset; ' if model is None else ''}calibrated from "
            f"the data in {c.seconds:.1f} s ({len(c.iterations)} passes over {c.frames} frames "
            f"per robot{'' if c.converged else ', not converged'}): {', '.join(keys)}"
        )
    if model is not None:
        note = f": {model.note}" if model.note else ""
        return f"sensor model: the dataset's ({model.origin}{note})"
    return "sensor model: none in the dataset and calibration off; camera-scaled defaults"


def print_run(run, out: Path | None = None) -> None:
    """The table of a :class:`teamslam.api.Run`, its health warnings, notes and files."""
    from teamslam.eval.estimates import has_ground_truth
    from teamslam.eval.metrics import pose_nees_warning
    from teamslam.eval.tables import team_table

    for warning in run.warnings:
        print(f"teamslam: {warning}", file=sys.stderr)
    for note in run.notes:
        print(note)
    if not run.by_mode:
        return
    print(team_table(run.by_mode))
    truth = run.dataset is not None and has_ground_truth(run.dataset)
    for name, m in run.by_mode.items():
        if "nis" in m:
            print_health(name, m)
        line = pose_nees_warning(m) if truth else None
        if line:
            print(f"warning ({name}): {line}", file=sys.stderr)
    if out is None:
        return
    print(f"\nwrote {out}/metrics.json, TUM trajectories, topview.png, errors.png")
    if run.written.get("mcap"):
        print_mcap_summary(run.written["mcap"])
    if run.written.get("report"):
        print(f"report: {run.written['report']}")


def print_mcap_summary(summary: dict) -> None:
    """One line: what an MCAP export wrote."""
    print(
        f"wrote {summary['path']}: {summary['messages']} messages on {len(summary['topics'])} "
        f"topics, {summary['bytes'] / 1e6:.2f} MB in {summary['seconds']:.2f} s"
    )


def print_health(name: str, metrics: dict) -> None:
    """The health warnings of a run's metrics, on standard error."""
    from teamslam.msckf.settings.health import health_warnings

    for line in health_warnings(
        {
            "nis": metrics["nis"],
            "gate_rejection_rate": metrics["gate_rejection_rate"],
            "odometry_residual_ratio": metrics["odometry_residual_ratio"],
        }
    ):
        print(f"warning ({name}): {line}", file=sys.stderr)
