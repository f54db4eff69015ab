"""What every command group shares: the parser class, argument types and the filter settings."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from teamslam.errors import InputError

__all__ = [
    "Parser",
    "UsageError",
    "default_data",
    "effective_settings",
    "non_negative_int",
    "positive_int",
    "print_health",
    "rate",
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


def positive_int(text: str) -> int:
    """An integer ≥ 1 (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def rate(text: str) -> float:
    """A number in [0, 1] (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {value}")
    return value


def non_negative_int(text: str) -> int:
    """An integer ≥ 0 (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 0, got {value}")
    return value


def default_data() -> Path:
    """``$TEAMSLAM_DATA`` or ``../shared/data`` relative to the working directory."""
    return Path(os.environ.get("TEAMSLAM_DATA", Path("..") / "shared" / "data"))


def settings_arguments(parser: argparse.ArgumentParser, calibration_flags: bool = True) -> None:
    """``--config`` and ``--set`` (and, unless told otherwise, when to calibrate)."""
    parser.add_argument(
        "--config", type=Path, default=None, help="YAML file of filter settings (key: value)"
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="a filter setting, e.g. --set object_std=0.01 (repeatable; wins over --config)",
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
    from teamslam.msckf.settings import load_config_file, parse_assignments, resolve_config

    file_values = load_config_file(args.config) if args.config is not None else {}
    flags = parse_assignments(args.set or [])
    if getattr(args, "window", None):
        flags["window"] = args.window
    if getattr(args, "objects_only", False):
        flags["use_geometric_features"] = False
    return resolve_config(
        dataset,
        file_values,
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


def print_health(name: str, metrics: dict) -> None:
    from teamslam.msckf.health import health_warnings

    for line in health_warnings(
        {
            "nis": metrics["nis"],
            "gate_rejection_rate": metrics["gate_rejection_rate"],
            "odometry_residual_ratio": metrics["odometry_residual_ratio"],
        }
    ):
        print(f"warning ({name}): {line}", file=sys.stderr)
