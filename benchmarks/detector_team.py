"""A rendered team seen through a detector: own tracking and association against oracle ids.

Renders a street of textured objects (``teamslam simulate --images --objects shapes --layout
street --no-markers``: three rooms in a row, robots spread evenly round one loop, each driving
the whole loop by default, so that it reaches what the others mapped long before), runs
the simulated detector on every image (its YOLO files, with the truth of every box kept aside),
builds the dataset the way a user does (``teamslam data from-images --rendered``: each box
measured in stereo, described by the image inside it) and runs separate filters and consensus
three ways on the same boxes:

* ``own`` — each robot names its boxes (tracking, appearance on) and the robots find their
  common objects (own association);
* ``own, no appearance`` — the same with ``tracking.appearance`` off;
* ``oracle`` — every box given its true object's id (``teamslam data oracle-ids``).

Prints per way the trajectory RMSE of both filters, the odometry's, own / oracle, IDF1, id
switches and false objects per 1000 frames, and the association's held and revoked pairs.
``--markdown FILE`` writes the table headed by the commit,
date, command and machine (``benchmarks/_markdown.py``).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/detector_team.py [--robots 3 --steps 420]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam import api
from teamslam.datasets.identity import oracle_object_ids
from teamslam.datasets.images import dataset_from_images, rendered_team_inputs
from teamslam.sim.detector import DetectorConfig
from teamslam.sim.render import RenderConfig, render_team, street_loop_length


def _row(name: str, run: api.Run, oracle: float | None) -> list[str]:
    sep, con = run.by_mode["separate"], run.by_mode["consensus"]
    tracking = con.get("tracking") or {}
    robots = tracking.get("robots", [])
    idf1 = np.mean([r["idf1"] for r in robots]) if robots else float("nan")
    switches = sum(r["id_switches"] for r in robots) if robots else 0
    links = (con.get("association") or {}).get("team") or {}
    held = links.get("held", "—")
    revoked = links.get("revoked", "—")
    precision = links.get("precision")
    ratio = "—" if oracle is None else f"{con['trajectory_rmse_avg_m'] / oracle:.2f}"
    return [
        name,
        f"{sep['trajectory_rmse_avg_m']:.4f}",
        f"{con['trajectory_rmse_avg_m']:.4f}",
        f"{con['odometry_rmse_avg_m']:.4f}",
        ratio,
        "—" if not robots else f"{idf1:.3f}",
        "—" if not robots else str(switches),
        "—" if not robots else f"{tracking.get('false_objects_per_1000_frames', 0.0):.1f}",
        f"{held} | {revoked}",
        "—" if precision is None else f"{precision:.3f}",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=420)
    parser.add_argument("--seed", type=int, default=17)
    add_option(parser)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        render = Path(tmp) / "street"
        config = RenderConfig(
            robots=args.robots,
            steps=args.steps,
            seed=args.seed,
            layout="street",
            objects="shapes",
            markers_per_wall=0,
        )
        render_team(config, render, detector=DetectorConfig())
        boxes = dataset_from_images(**rendered_team_inputs(render), progress=False)
    settings = {"filter.window": 10}
    oracle = api.run(oracle_object_ids(boxes), mode="compare", settings=settings, report=False)
    own = api.run(boxes, mode="compare", settings=settings, report=False)
    plain = api.run(
        boxes,
        mode="compare",
        settings={**settings, "tracking.appearance": False},
        report=False,
    )
    reference = oracle.by_mode["consensus"]["trajectory_rmse_avg_m"]
    header = [
        "ids",
        "separate RMSE [m]",
        "consensus RMSE [m]",
        "odometry RMSE [m]",
        "consensus / oracle",
        "IDF1",
        "id switches",
        "false objects / 1000 frames",
        "association held | revoked",
        "inter-robot precision",
    ]
    rows = [
        _row("own (tracking + association, appearance)", own, reference),
        _row("own, no appearance", plain, reference),
        _row("oracle (true id of every box)", oracle, None),
    ]
    counts = {}
    for record in boxes.metadata["images"]["robots"]:
        for key, value in record["detections"].items():
            if isinstance(value, int):
                counts[key] = counts.get(key, 0) + value
    note = (
        f"{args.robots} robots × {args.steps + 1} frames (640×480), each driving "
        f"{args.steps * config.step_length:.1f} m of the street's "
        f"{street_loop_length(config):.1f} m loop, street of {boxes.object_ids.size} objects, "
        f"seed {args.seed}, `filter.window = 10`; "
        f"{counts['boxes_read']} boxes: {counts['right box']} in stereo by the right image's "
        f"boxes, {counts['patch']} by their patch, {counts['monocular']} monocular."
    )
    md = Markdown(args.markdown)
    md.table(
        "Objects from a detector: a rendered street, own ids against the oracle's", header, note
    )
    print(" | ".join(header))
    for row in rows:
        md.row(*row)
        print(" | ".join(row))
    print(note)
    md.end()
    md.write()


if __name__ == "__main__":
    main()
