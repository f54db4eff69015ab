"""A run as one MCAP file with standard ROS 2 schemas (Foxglove, RViz via rosbag2, rosbags).

Per robot ``i``: ``/robot_<i>/pose``, ``/robot_<i>/path`` (every ``path_every``-th frame),
``/robot_<i>/objects`` (final map with 3σ ellipsoids), ``/ground_truth/robot_<i>/pose``,
``/tf``, and ``/association`` for a run with the robots' own association; a ``--compare`` run's
separate filters under ``/separate``. Written by ``rosbags``' rosbag2 MCAP storage and moved out
of its bag directory, so it is a plain ``.mcap`` that ``ros2 bag play`` also accepts.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.eval.estimates import FILENAME, RobotEstimates, load_estimates
from teamslam.eval.runs import require_run_file
from teamslam.ros2 import messages as m

__all__ = ["export_mcap", "find_runs", "write_mcap"]

POSE = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
MARKERS = "visualization_msgs/msg/MarkerArray"
TF = "tf2_msgs/msg/TFMessage"


def find_runs(result_dir: str | Path, writing: bool = False) -> dict[str, Path]:
    """``{topic prefix: estimates file}`` of the runs in a result directory (one with
    ``run.json``, or one being written: ``writing``)."""
    result_dir = Path(result_dir)
    if not writing:
        require_run_file(result_dir)
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
    associations: dict[str, list[dict]] | None = None,
) -> dict:
    """Write the estimates of one or more runs (``{topic prefix: robots}``) to ``out``.

    ``associations``: per topic prefix, per robot the run's per-link association (``pairs`` of
    own and neighbour ids, :meth:`~teamslam.msckf.consensus.protocol.ConsensusProtocol.
    association_summary`), drawn as lines on ``<prefix>/association``.

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
        per_robot = (associations or {}).get(prefix)
        if per_robot:
            last = max(int(r.stamps_ns[-1]) for r in robots)
            lines = _association_lines(robots, per_robot, last)
            records.append((last, f"{prefix}/association", MARKERS, m.serialize(lines, MARKERS)))
    counts = m.write_mcap_records(records, out)
    return {
        "path": str(out),
        "messages": sum(counts.values()),
        "topics": counts,
        "bytes": out.stat().st_size,
        "seconds": time.perf_counter() - begin,
    }


def _association_lines(robots: list[RobotEstimates], per_robot: list[dict], stamp: int):
    """One ``LINE_LIST`` marker per link ``i < j``: a segment per matched pair."""
    t = m._types()
    Marker, Point = t["visualization_msgs/msg/Marker"], t["geometry_msgs/msg/Point"]
    position = [
        dict(zip(np.asarray(r.object_ids).tolist(), np.asarray(r.objects), strict=True))
        for r in robots
    ]
    markers = []
    for i, links in enumerate(per_robot):
        for key, link in sorted(links.items(), key=lambda kv: int(kv[0])):
            j = int(key)
            if j <= i or j >= len(robots) or not link.get("pairs"):
                continue
            points = []
            for own_id, their_id in link["pairs"]:
                a, b = position[i].get(int(own_id)), position[j].get(int(their_id))
                if a is None or b is None:
                    continue
                points += [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in (a, b)]
            markers.append(
                Marker(
                    header=m.header(stamp, "world"),
                    ns=f"link_{i}_{j}",
                    id=0,
                    type=Marker.LINE_LIST,
                    action=Marker.ADD,
                    pose=t["geometry_msgs/msg/Pose"](
                        position=Point(x=0.0, y=0.0, z=0.0),
                        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    ),
                    scale=t["geometry_msgs/msg/Vector3"](x=0.05, y=0.0, z=0.0),
                    color=m._colour(i, 0.8),
                    lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
                    frame_locked=False,
                    points=points,
                    colors=[],
                    texture_resource="",
                    texture=t["sensor_msgs/msg/CompressedImage"](
                        header=m.header(0, ""), format="", data=np.zeros(0, np.uint8)
                    ),
                    uv_coordinates=[],
                    text="",
                    mesh_resource="",
                    mesh_file=t["visualization_msgs/msg/MeshFile"](
                        filename="", data=np.zeros(0, np.uint8)
                    ),
                    mesh_use_embedded_materials=False,
                )
            )
    return t["visualization_msgs/msg/MarkerArray"](markers=markers)


def _associations(paths: dict[str, Path]) -> dict[str, list[dict]]:
    """Per run (topic prefix) the per-robot association its ``result.json`` recorded."""
    import json

    out = {}
    for prefix, path in paths.items():
        result = Path(path).parent / "result.json"
        if not result.is_file():
            continue
        try:
            extra = json.loads(result.read_text()).get("extra", {})
        except (OSError, ValueError):
            continue
        association = extra.get("association") or [
            s.get("association", {}) for s in extra.get("per_robot", [])
        ]
        if any(association):
            out[prefix] = association
    return out


def export_mcap(
    result_dir: str | Path, out: str | Path, path_messages: int = 100, writing: bool = False
) -> dict:
    """Export the run(s) in ``result_dir`` (``estimates.npz``) to the MCAP file ``out`` (with
    the association lines of a run whose robots associated their objects themselves);
    ``writing``: ``result_dir`` is a run directory being written (no ``run.json`` yet)."""
    paths = find_runs(result_dir, writing)
    runs = {prefix: load_estimates(path)[1] for prefix, path in paths.items()}
    return write_mcap(runs, out, path_messages=path_messages, associations=_associations(paths))
