"""The FEJ paper's Tables 1 and 2 on its published environment files and on generated ones.

For each environment (1, 2) and feature count (20, 60, 100), the standard, ideal and FEJ EKFs'
robot-1 pose NEES over the same Monte Carlo runs on:

* ``published`` — the paper's own environment files (``fej-environments/`` in the data folder);
* ``published, y/2`` — the same files with the data's observation y-noise at half its σ while
  the filters assume the full σ: how the published generator's truncated noise draws it;
* ``generated`` — :func:`teamslam.ekf2d.environments.environment`, the environment users make;

beside the paper's value. A cell is ``mean ± 2 standard errors (median, runs above the 97.5% χ²
bound)``: single divergent runs dominate a mean, whose Monte Carlo error is then wide.
Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/fej_environments.py --data ../shared/data \
        --runs 100 [--markdown docs/results/generated/fej-environments.md]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _markdown import Markdown, add_option
from teamslam import api
from teamslam.ekf2d.experiments import FILTERS, LABELS, monte_carlo
from teamslam.paper.values import paper_values

VARIANTS = ("published", "published, y/2", "generated")


def _paper_nees(env: int) -> dict[tuple[int, str], float]:
    """``(features, filter label) → robot-1 pose NEES`` of the paper's table for ``env``."""
    out = {}
    for v in paper_values("fej", str(env)):
        if v.column == "Robot 1 Pose NEES":
            count, _, label = v.row.split(" ", 2)
            out[int(count), label] = v.value
    return out


def _cell(table: dict) -> str:
    return (
        f"{table['r1_pose_nees']:.2f} ± {2 * table['r1_pose_nees_sem']:.2f} "
        f"({table['r1_pose_nees_median']:.2f}, "
        f"{table['r1_runs_above_bound']})"
    )


def measure(data: Path, runs: int, workers: int | None) -> list[list[str]]:
    """One row per environment, feature count and filter."""
    rows = []
    for env in (1, 2):
        paper = _paper_nees(env)
        folder = data / "fej-environments"
        for count in (20, 60, 100):
            files = [
                folder / f"RobotsWaypoints_{env}.mat",
                folder / f"CheckedTrueState_{count}features_{env}.mat",
            ]
            published = api.fej_environment(env, count, files)
            generated = api.fej_environment(env, count)
            results = {
                "published": monte_carlo(published, runs, workers=workers, progress=False),
                "published, y/2": monte_carlo(
                    published,
                    runs,
                    workers=workers,
                    progress=False,
                    observation_noise_scale=(1.0, 0.5),
                ),
                "generated": monte_carlo(generated, runs, workers=workers, progress=False),
            }
            for name in FILTERS:
                label = LABELS[name]
                theirs = paper.get((count, label))
                rows.append(
                    [f"{env}", f"{count}", label, "—" if theirs is None else f"{theirs:.2f}"]
                    + [_cell(results[v].table[name]) for v in VARIANTS]
                )
            print(f"environment {env}, {count} features done", file=sys.stderr, flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--workers", type=int, default=None)
    add_option(parser)
    args = parser.parse_args()
    if not (args.data / "fej-environments").is_dir():
        parser.error(f"{args.data / 'fej-environments'} does not exist")
    md = Markdown(args.markdown)
    rows = measure(args.data, args.runs, args.workers)
    head = ["env", "features", "EKF", "paper", *VARIANTS]
    md.table(
        f"Robot-1 pose NEES, {args.runs} Monte Carlo runs: mean ± 2 SE (median, runs above the "
        "97.5% χ² bound)",
        head,
    )
    print(" | ".join(head))
    for row in rows:
        md.row(*row)
        print(" | ".join(row))
    md.end()
    md.write()


if __name__ == "__main__":
    main()
