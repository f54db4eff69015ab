"""A run as one MCAP file with standard ROS 2 schemas (Foxglove, RViz via rosbag2, rosbags).

Topics, per robot ``i`` (the team's robot index, from 0):

* ``/robot_<i>/pose`` — ``geometry_msgs/msg/PoseStamped``, frame ``world``, the filtered
  ``T_world_body`` of every frame, stamped with the dataset's timestamps (or frame index ×
  period);
* ``/robot_<i>/path`` — ``nav_msgs/msg/Path``, the trajectory so far, every ``path_every``-th
  frame and at the last one (a path per frame would grow the file quadratically);
* ``/robot_<i>/objects`` — ``visualization_msgs/msg/MarkerArray``, the robot's final map at its
  last stamp: each object a sphere and its 3σ ellipsoid (when the run kept the covariances);
* ``/ground_truth/robot_<i>/pose`` — ``PoseStamped`` of the dataset's ground truth, when it has
  one (written once, with the main run);
* ``/tf`` — ``tf2_msgs/msg/TFMessage``: ``world → robot_<i>/base_link`` (estimate) and
  ``world → robot_<i>/ground_truth``.

With ``--compare`` results (``separate/`` and ``consensus/``) the consensus run has the topics
above and the separate run the same under ``/separate``. The file is written by ``rosbags``'
rosbag2 MCAP storage (zstd chunks, schemas ``ros2msg``, rosbag2 metadata) and moved out of its
bag directory, so it is a plain ``.mcap`` that ``ros2 bag play`` also accepts.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.eval.estimates import FILENAME, RobotEstimates, load_estimates
from teamslam.ros2 import messages as m

__all__ = ["export_mcap", "find_runs", "write_mcap"]

POSE = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
MARKERS = "visualization_msgs/msg/MarkerArray"
TF = "tf2_msgs/msg/TFMessage"


def find_runs(result_dir: str | Path) -> dict[str, Path]:
    """``{topic prefix: estimates file}`` of the runs in a result directory."""
    result_dir = Path(result_dir)
    if (result_dir / FILENAME).exists():
        return {"": result_dir / FILENAME}
    found = {
        p.parent.name: p for p in sorted(result_dir.glob(f"*/{FILENAME}")) if p.parent.is_dir()
    }
    if not found:
        raise InputError(
            f"{result_dir}: no {FILENAME} (neither there nor in a sub-directory); "
            "it is written by `teamslam run ... --out DIR`"
        )
    main = "consensus" if "consensus" in found else next(iter(found))
    return {("" if name == main else f"/{name}"): path for name, path in found.items()}


def _scene_extent(robots: list[RobotEstimates]) -> float:
    points = [r.poses[:, :3, 3] for r in robots] + [r.objects for r in robots]
    allp = np.concatenate([p.reshape(-1, 3) for p in points])
    return float(np.ptp(allp, axis=0).max()) if allp.size else 0.0


def write_mcap(
    runs: dict[str, list[RobotEstimates]],
    out: str | Path,
    path_messages: int = 100,
    n_sigma: float = 3.0,
) -> dict:
    """Write the estimates of one or more runs (``{topic prefix: robots}``) to ``out``.

    Returns a summary: messages per topic, bytes, seconds.
    """

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    begin = time.perf_counter()
    everything = [r for robots in runs.values() for r in robots]
    extent = _scene_extent(everything)
    sphere = 0.01 * extent if extent > 0 else 1.0
    records: list[tuple[int, str, str, bytes]] = []
    for prefix, robots in runs.items():
        for i, r in enumerate(robots):
            base = f"{prefix}/robot_{i}"
            stamps = r.stamps_ns
            n = len(stamps)
            every = max(1, math.ceil(n / max(path_messages, 1)))
            estimate = m.poses_stamped(r.poses, stamps)
            truth = None
            if r.ground_truth is not None and not prefix:
                truth = m.poses_stamped(r.ground_truth, stamps)
            for k in range(n):
                s = int(stamps[k])
                records.append((s, f"{base}/pose", POSE, m.serialize(estimate[k], POSE)))
                frames = [(estimate[k].pose, "world", f"{base.lstrip('/')}/base_link")]
                if truth is not None:
                    records.append(
                        (s, f"/ground_truth{base}/pose", POSE, m.serialize(truth[k], POSE))
                    )
                    frames.append((truth[k].pose, "world", f"{base.lstrip('/')}/ground_truth"))
                records.append((s, "/tf", TF, m.serialize(m.tf_message(frames, s), TF)))
                if (k + 1) % every == 0 or k == n - 1:
                    path = m.path_msg(estimate[: k + 1], stamps[: k + 1])
                    records.append((s, f"{base}/path", PATH, m.serialize(path, PATH)))
            last = int(stamps[-1])
            markers = m.object_markers(
                r.object_ids, r.objects, r.object_covs, last, i, sphere, n_sigma=n_sigma
            )
            records.append((last, f"{base}/objects", MARKERS, m.serialize(markers, MARKERS)))
    counts = m.write_mcap_records(records, out)
    return {
        "path": str(out),
        "messages": sum(counts.values()),
        "topics": counts,
        "bytes": out.stat().st_size,
        "seconds": time.perf_counter() - begin,
    }


def export_mcap(result_dir: str | Path, out: str | Path, path_messages: int = 100) -> dict:
    """Export the run(s) in ``result_dir`` (``estimates.npz``) to the MCAP file ``out``."""
    runs = {prefix: load_estimates(path)[1] for prefix, path in find_runs(result_dir).items()}
    return write_mcap(runs, out, path_messages=path_messages)
