"""``teamslam paper``: every table and figure of both papers, the paper's numbers beside ours."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from teamslam.cli._common import Parser, default_data, positive_int

__all__ = ["register"]


def _settings(args: argparse.Namespace):
    from teamslam.paper import PaperSettings

    changes = {
        name: value
        for name, value in (
            ("fej_runs", args.runs),
            ("seeds", args.seeds),
            ("steps", args.steps),
            ("frames", args.frames),
            ("workers", args.workers),
            ("scheduler", args.scheduler),
            ("team_sizes", tuple(args.robots) if args.robots else None),
            ("fej_features", tuple(args.features) if args.features else None),
        )
        if value is not None
    }
    if args.quick:
        return PaperSettings.quick(**changes)
    label = {"label": "custom"} if changes.keys() - {"workers", "scheduler"} else {}
    return PaperSettings(**changes, **label)


def _show(result, as_json: bool) -> None:
    if as_json:
        return
    print(result.text())
    print(f"  ({result.seconds:.1f} s CPU)\n", flush=True)


def _finish(results, args: argparse.Namespace, written: list[str]) -> int:
    if args.json:
        print(json.dumps([r for item in results for r in item.records()], indent=1))
    elif written:
        print("wrote " + ", ".join(written))
    return 0


def _resumed(reproducer, args: argparse.Namespace) -> None:
    store = reproducer.store
    if args.resume and store is not None:
        print(
            f"resumed: {store.loaded} task(s) read back from {store.directory}, {store.saved} run",
            file=sys.stderr,
        )


def _cmd_list(args: argparse.Namespace) -> int:
    from teamslam.paper import ITEMS
    from teamslam.paper.values import paper_values

    rows = []
    for item in ITEMS.values():
        flag = (
            "--victoria-park"
            if item.kind == "table" and item.number == "victoria-park"
            else (f"--{item.kind} {item.number}")
        )
        count = len(paper_values(item.paper, _table_name(item)))
        rows.append((item.key, f"teamslam paper {item.paper} {flag}", item.data, count, item.title))
    if args.json:
        keys = ("key", "command", "data", "paper_values", "title")
        print(json.dumps([dict(zip(keys, r, strict=True)) for r in rows], indent=1))
        return 0
    for key, command, data, count, title in rows:
        print(f"{key:<18} {command:<38} {data:<26} {count:>3} values  {title}")
    print("\nteamslam paper all --out DIR [--quick]   every one, with report.html")
    return 0


def _table_name(item) -> str:
    roman = {"1": "I", "2": "II", "3": "III", "4": "IV"}
    if item.kind != "table":
        return "-"
    return roman[item.number] if item.paper == "dvi" else item.number


def _header() -> str:
    """The first line of each Markdown file: commit, date, this command, the machine (taken as
    the run starts, so that edits made while it runs are not blamed on it)."""
    from teamslam.eval.provenance import command_line, measured_header

    return measured_header(command_line("teamslam"))


def _cmd_one(args: argparse.Namespace) -> int:
    from teamslam.errors import InputError
    from teamslam.paper import Reproducer, item_key
    from teamslam.paper.reproduce import task_store

    if getattr(args, "victoria_park", False):
        key = item_key(args.paper, "victoria-park", "")
    elif args.table is not None:
        key = item_key(args.paper, "table", args.table)
    else:
        key = item_key(args.paper, "figure", args.figure)
    settings = _settings(args)
    if args.resume and args.out is None:
        raise InputError("--resume continues the tasks kept in an output directory: give --out")
    keep = args.out is not None and (args.resume or args.scheduler is not None)
    store = task_store(args.out, settings, args.data, args.resume) if keep else None
    header = _header()  # the code and machine as the run starts
    if not args.json:
        print(settings.describe(), flush=True)
    reproducer = Reproducer(settings, args.data, store)
    result = reproducer.build(key)
    _resumed(reproducer, args)
    _show(result, args.json)
    written = [] if args.out is None else [str(p) for p in result.write(args.out, header)]
    return _finish([result], args, written)


def _cmd_all(args: argparse.Namespace) -> int:
    from teamslam.errors import InputError
    from teamslam.paper import ITEMS, reproduce_all

    unknown = [k for k in args.only or [] if k not in ITEMS]
    if unknown:
        raise InputError(
            f"--only: no table or figure {', '.join(unknown)} (see teamslam paper list)"
        )
    settings = _settings(args)
    if not args.json:
        print(settings.describe(), flush=True)
    results, reproducer = reproduce_all(
        args.out,
        settings,
        args.data,
        keys=args.only,
        on_done=lambda r: _show(r, args.json),
        header=_header(),
        resume=args.resume,
    )
    _resumed(reproducer, args)
    if not args.json:
        print(reproducer.time_text(), file=sys.stderr)
    return _finish(results, args, [f"{args.out}/ (*.md, *.json, *.png, paper.json, report.html)"])


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--quick",
        action="store_true",
        help="fewer Monte Carlo runs and seeds, shorter simulated teams (stated in the output)",
    )
    parser.add_argument("--runs", type=positive_int, default=None, help="FEJ Monte Carlo runs")
    parser.add_argument(
        "--seeds", type=positive_int, default=None, help="simulated teams per team size"
    )
    parser.add_argument(
        "--steps", type=positive_int, default=None, help="steps of each simulated robot"
    )
    parser.add_argument(
        "--robots", type=positive_int, nargs="+", default=None, help="simulated team sizes"
    )
    parser.add_argument(
        "--features",
        type=int,
        nargs="+",
        choices=(20, 60, 100),
        default=None,
        help="FEJ feature counts",
    )
    parser.add_argument(
        "--frames",
        type=positive_int,
        default=None,
        help="only the first FRAMES frames of each robot of the real data",
    )
    parser.add_argument(
        "--workers", type=positive_int, default=None, help="processes (default: all cores)"
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run every task on the Dask scheduler at ADDRESS (tcp://host:8786; the 'cluster' "
        "extra) instead of --workers processes",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="keep each task's result in OUT/tasks as it finishes (always so with --scheduler), "
        "and read back those an interrupted run of the same settings kept there: only the "
        "missing ones run",
    )
    parser.add_argument(
        "--data", type=Path, default=default_data(), help="data directory (default: $TEAMSLAM_DATA)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON record per cell")


def register(sub) -> None:
    """Add ``teamslam paper``."""
    paper = sub.add_parser(
        "paper",
        help="every table and figure of both papers, the paper's numbers beside ours",
        description="Run the experiments behind the distributed-MSCKF paper (dvi) and the FEJ "
        "multi-robot EKF paper (fej) and print each table with the paper's value and ours side "
        "by side (and ours − theirs where the data is the paper's own), saying what differs in "
        "the setting; with --out write Markdown, JSON and PNG files.",
    )
    paper_sub = paper.add_subparsers(dest="paper_command", metavar="ACTION", parser_class=Parser)
    paper_sub.required = True
    listing = paper_sub.add_parser("list", help="the tables and figures that can be reproduced")
    listing.add_argument("--json", action="store_true", help="print JSON")
    listing.set_defaults(handler=_cmd_list)
    for name, tables, figures, title in (
        ("dvi", ("1", "2", "3", "4"), ("3", "4"), "the distributed-MSCKF paper"),
        ("fej", ("1", "2"), ("4", "5", "6"), "the FEJ multi-robot EKF paper"),
    ):
        p = paper_sub.add_parser(name, help=f"a table or figure of {title}")
        which = p.add_mutually_exclusive_group(required=True)
        which.add_argument("--table", choices=tables, default=None, help="the paper's table N")
        which.add_argument(
            "--figure", choices=figures, default=None, help="the paper's figure N (PNG with --out)"
        )
        if name == "fej":
            which.add_argument(
                "--victoria-park",
                action="store_true",
                help="Victoria Park RMSE beside the published code's (and Figure 6)",
            )
        _common(p)
        p.add_argument("--out", type=Path, default=None, help="directory for .md, .json, .png")
        p.set_defaults(handler=_cmd_one, paper=name)
    everything = paper_sub.add_parser("all", help="every table and figure, and report.html")
    _common(everything)
    everything.add_argument(
        "--only",
        nargs="+",
        default=None,
        metavar="KEY",
        help="only these tables and figures (keys of teamslam paper list); the experiments "
        "they share run once",
    )
    everything.add_argument("--out", type=Path, required=True, help="output directory")
    everything.set_defaults(handler=_cmd_all)
