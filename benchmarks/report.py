"""Time of `teamslam eval` and of the HTML report on a run directory, and the report's size.

Run on demand, after ``make run`` (or on any run directory)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/report.py [results/team5-run] [--repeats 5]

Prints the median seconds to read and evaluate the runs (APE/RPE, every alignment), to build
the report (figures included), and its size; with Chromium installed, the median seconds of a
headless render to PNG.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

from teamslam.eval.report import build_report, evaluate_runs
from teamslam.eval.runs import load_runs


def _median(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", nargs="?", type=Path, default=Path("results/team5-run"))
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    runs = load_runs(args.run)
    print(f"{args.run}: {len(runs)} run(s), {len(runs[0].estimates)} robots")
    for align in ("none", "se3", "sim3", "first-pose"):
        t = _median(lambda a=align: evaluate_runs(runs, align=a), args.repeats)
        print(f"evaluate (align {align:<10}) median {t:8.4f} s")
    t = _median(lambda: load_runs(args.run), args.repeats)
    print(f"read run directory          median {t:8.4f} s")
    evaluations = evaluate_runs(runs)
    text = ""

    def build() -> None:
        nonlocal text
        text = build_report(runs, evaluations)

    t = _median(build, args.repeats)
    print(f"build report                median {t:8.4f} s   size {len(text.encode()) / 1e6:.2f} MB")
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("Chromium not installed; render time skipped")
        return
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "report.html"
        page.write_text(text, encoding="utf-8")
        command = [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            f"--user-data-dir={tmp}/profile",
            "--window-size=1280,1400",
            f"--screenshot={tmp}/shot.png",
            page.as_uri(),
        ]
        t = _median(
            lambda: subprocess.run(command, capture_output=True, timeout=120, check=True),
            args.repeats,
        )
        print(f"Chromium headless render    median {t:8.4f} s")


if __name__ == "__main__":
    with threadpool_limits(1):
        main()
