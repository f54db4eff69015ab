"""The FEJ paper's Tables 1 and 2 on its published environment files and on generated ones.

For each environment (1, 2) and feature count (20, 60, 100), the standard, ideal and FEJ EKFs'
robot-1 pose NEES over the same Monte Carlo runs on:

* ``published`` — the paper's own environment files (``fej-environments/`` in the data folder);
* ``published, y/2`` — the same files with the data's observation y-noise at half its σ while
  the filters assume the full σ: how the published generator's truncated noise draws it;
* ``generated`` — :func:`teamslam.ekf2d.environments.environment`, the environment users make;

beside the paper's value. A cell is ``mean ± 2 standard errors (median, runs above the 97.5% χ²
bound)``: single divergent runs dominate a mean, whose Monte Carlo error is then wide.

With ``--layouts K`` a second table runs the same filters on K generated layouts of each
configuration (``layout`` 0 … K−1, the same runs on each) and sets the published file beside
the spread over layouts: the layouts' means and medians (median of the K, with their range),
the runs of all layouts pooled, and how many layouts lie below the published file. One layout
against another differs by more than the Monte Carlo error of either, so a single published
file is compared with the kind of environment the generator makes, not with one draw of it.
Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/fej_environments.py --data ../shared/data \
        --runs 100 [--layouts 10] [--markdown docs/results/generated/fej-environments.md]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy import stats

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


def _spread(values: np.ndarray) -> str:
    return f"{np.median(values):.2f} ({values.min():.2f}–{values.max():.2f})"


def _layout_row(published, layouts: list, name: str) -> list[str]:
    """Published file against the generated layouts for one filter (robot 1)."""
    mine = published.run_pose_nees[name][:, 0]
    each = [r.run_pose_nees[name][:, 0] for r in layouts]
    means = np.array([v.mean() for v in each])
    medians = np.array([np.median(v) for v in each])
    pooled = np.concatenate(each)
    bound = stats.chi2.ppf(0.975, 3) / 3
    # the pooled mean's error from the spread of the layouts' means (layouts are the unit)
    sem = means.std(ddof=1) / np.sqrt(len(means)) if len(means) > 1 else np.nan
    return [
        f"{mine.mean():.2f} ({np.median(mine):.2f}, {np.mean(mine > bound):.0%})",
        f"{pooled.mean():.2f} ± {2 * sem:.2f} ({np.median(pooled):.2f}, "
        f"{np.mean(pooled > bound):.0%})",
        _spread(means),
        _spread(medians),
        f"{np.sum(mine.mean() > means)} / {np.sum(np.median(mine) > medians)}",
        f"{np.median(mine) / np.median(pooled):.2f}",
    ]


def measure(
    data: Path, runs: int, workers: int | None, layouts: int = 0
) -> tuple[list[list[str]], list[list[str]]]:
    """One row per environment, feature count and filter: the variants' table and, with
    ``layouts``, the published file against that many generated layouts."""
    rows, spread = [], []
    for env in (1, 2):
        paper = _paper_nees(env)
        folder = data / "fej-environments"
        for count in (20, 60, 100):
            files = [
                folder / f"RobotsWaypoints_{env}.mat",
                folder / f"CheckedTrueState_{count}features_{env}.mat",
            ]
            published = api.fej_environment(env, count, files)
            drawn = [
                monte_carlo(
                    api.fej_environment(env, count, layout=k), runs, workers=workers, progress=False
                )
                for k in range(1, layouts)
            ]
            results = {
                "published": monte_carlo(published, runs, workers=workers, progress=False),
                "published, y/2": monte_carlo(
                    published,
                    runs,
                    workers=workers,
                    progress=False,
                    observation_noise_scale=(1.0, 0.5),
                ),
                "generated": monte_carlo(
                    api.fej_environment(env, count), runs, workers=workers, progress=False
                ),
            }
            for name in FILTERS:
                label = LABELS[name]
                theirs = paper.get((count, label))
                rows.append(
                    [f"{env}", f"{count}", label, "—" if theirs is None else f"{theirs:.2f}"]
                    + [_cell(results[v].table[name]) for v in VARIANTS]
                )
                if layouts:
                    row = _layout_row(results["published"], [results["generated"], *drawn], name)
                    spread.append([f"{env}", f"{count}", label, *row])
            print(f"environment {env}, {count} features done", file=sys.stderr, flush=True)
    return rows, spread


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument(
        "--layouts", type=int, default=0, help="also compare with this many generated layouts"
    )
    add_option(parser)
    args = parser.parse_args()
    if not (args.data / "fej-environments").is_dir():
        parser.error(f"{args.data / 'fej-environments'} does not exist")
    md = Markdown(args.markdown)
    rows, spread = measure(args.data, args.runs, args.workers, args.layouts)
    md.table_of(
        f"Robot-1 pose NEES, {args.runs} Monte Carlo runs: mean ± 2 SE (median, runs above the "
        "97.5% χ² bound)",
        ["env", "features", "EKF", "paper", *VARIANTS],
        rows,
    )
    if spread:
        md.table_of(
            f"Robot-1 pose NEES, published file against {args.layouts} generated layouts, "
            f"{args.runs} runs each: mean (median, share of runs above the 97.5% χ² bound); "
            "pooled: mean ± 2 SE over layouts (median, share above); layouts: median (range)",
            [
                "env",
                "features",
                "EKF",
                "published",
                f"{args.layouts} layouts pooled",
                "layouts' means",
                "layouts' medians",
                "layouts below published (mean / median)",
                "published / pooled median",
            ],
            spread,
        )
    md.write()


if __name__ == "__main__":
    main()
