"""Speed and accuracy of box stereo and appearance descriptors per stereo frame, one core.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/box_stereo.py [--frames 20] [--boxes 10]
        [--markdown FILE]

For each image size (640 × 480, and 1241 × 376 with a KITTI-like focal length and baseline) a
rendered robot's frames get about ``--boxes`` boxes each, as a detector would give: the tight
box around every marker wholly visible in both images, and as many boxes on the walls as make
up the rest (a detector's other objects: sides of 5 to 30 % of the image height, and in a
second run 30 to 90 %, large boxes whose cost must not grow with their size). Per frame, CPU
milliseconds of this process (process time: what the work costs, whatever else the machine
runs) with OpenCV and BLAS on one thread (medians over the frames) of
:meth:`BoxStereo.measure` (the patch search, no right-image boxes), of the default appearance
descriptor on the left image, and of both; then the share of boxes measured in stereo, and
for the markers the share whose right centre lies within 1 px of the renderer's truth (the
projection of the wall point behind the left box centre).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _markdown import Markdown, add_option
from teamslam.frontend import FrontendConfig, StereoRig
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.appearance import DEFAULT_DESCRIPTOR, describe
from teamslam.frontend.boxes import BoxStereo
from teamslam.frontend.detections import ImageDetections
from teamslam.sim.render import T_CAM_BODY, RenderConfig, render_stereo, render_team

SIZES = {
    "640×480": {"image_size": (640, 480), "focal": 420.0, "baseline": 0.2},
    "1241×376": {"image_size": (1241, 376), "focal": 718.0, "baseline": 0.54},
}


def frame_boxes(team, frame: int, count: int, sides: tuple[float, float], rng):
    """Marker boxes (left image) and wall boxes up to ``count``: ``(boxes, marker ids with
    -1 for a wall box)``."""
    config = team.config
    room = team.room
    w, h = config.image_size
    ids, _, side = team.visible_markers(0, frame)
    ids = ids[side >= 12][:count]
    corners = room.marker_corners[np.searchsorted(room.marker_ids, ids)]
    z = team.project(0, frame, corners.reshape(-1, 3)).reshape(-1, 4, 4)[..., :2]
    boxes = [np.concatenate([z.min(axis=1), z.max(axis=1)], axis=1)]
    extra = count - len(ids)
    size = rng.uniform(*sides, (extra, 2)) * h
    corner = rng.uniform(0, 1, (extra, 2)) * ([w - 1, h - 1] - size)
    boxes.append(np.concatenate([corner, corner + size], axis=1))
    return np.concatenate(boxes), np.concatenate([ids, np.full(extra, -1)])


SIDES = {"typical": (0.05, 0.3), "large": (0.3, 0.9)}


def measure_size(name: str, sides: str, frames: int, count: int, seed: int) -> dict:
    """Timings and accuracy at one image size with wall boxes of ``SIDES[sides]``."""
    config = RenderConfig(robots=1, steps=frames - 1, seed=seed, **SIZES[name])
    team = render_team(config)
    rig = StereoRig.rectified(config.image_size, config.camera(), T_CAM_BODY)
    stereo = BoxStereo(rig, FrontendConfig())
    rng = np.random.default_rng(seed)
    t_stereo, t_describe, n_boxes, n_stereo, n_markers, errors = [], [], 0, 0, 0, []
    for k in range(frames):
        left, right = render_stereo(team.room, team.T_world_cam(0, k), rng)
        boxes, ids = frame_boxes(team, k, count, SIDES[sides], rng)
        detections = ImageDetections(boxes, np.zeros(len(boxes), np.int64), np.ones(len(boxes)))
        t0 = time.process_time()
        m = stereo.measure(left, right, detections)
        t1 = time.process_time()
        describe(left, boxes, DEFAULT_DESCRIPTOR)
        t2 = time.process_time()
        t_stereo.append(t1 - t0)
        t_describe.append(t2 - t1)
        n_boxes += len(boxes)
        n_stereo += int(np.sum(m.source == "patch"))
        n_markers += int(np.sum(ids >= 0))
        marker = (ids >= 0) & (m.source == "patch")
        if marker.any():
            truth = team.project(0, k, team.points_behind(0, k, m.z[marker, :2]))
            errors.append(np.abs(m.z[marker, 2:] - truth[:, 2:]).max(axis=1))
    errors = np.concatenate(errors) if errors else np.zeros(0)
    both = np.add(t_stereo, t_describe)
    return {
        "boxes": n_boxes / frames,
        "stereo": 1e3 * float(np.median(t_stereo)),
        "describe": 1e3 * float(np.median(t_describe)),
        "both": 1e3 * float(np.median(both)),
        "stereo share": n_stereo / max(n_boxes, 1),
        "markers": f"{errors.size} of {n_markers}",
        "within 1 px": float(np.mean(errors < 1.0)) if errors.size else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--boxes", type=int, default=10, help="boxes per frame")
    parser.add_argument("--seed", type=int, default=0)
    add_option(parser)
    args = parser.parse_args(argv)
    md = Markdown(args.markdown)
    require_cv2("the box stereo benchmark").setNumThreads(1)
    title = "Box stereo and appearance descriptors: CPU time per stereo frame, one thread (medians)"
    note = (
        f"{args.frames} rendered frames per size, {args.boxes} boxes per frame; descriptor "
        f"{DEFAULT_DESCRIPTOR}; stereo share: boxes measured in stereo by their patch; "
        "markers in stereo: marker boxes measured in stereo of all marker boxes; markers within "
        "1 px: of those, right centre against the renderer's truth."
    )
    columns = [
        "image",
        "wall boxes",
        "boxes / frame",
        "box stereo ms",
        "descriptors ms",
        "both ms",
        "stereo share",
        "markers in stereo",
        "markers within 1 px",
    ]
    md.table(title, columns, note)
    print(title)
    print(note)
    print("  ".join(columns))
    for name, sides in ((name, sides) for name in SIZES for sides in SIDES):
        r = measure_size(name, sides, args.frames, args.boxes, args.seed)
        lo, hi = SIDES[sides]
        row = (
            name,
            f"{sides} ({lo:.0%}–{hi:.0%} of the height)",
            f"{r['boxes']:.1f}",
            f"{r['stereo']:.2f}",
            f"{r['describe']:.2f}",
            f"{r['both']:.2f}",
            f"{r['stereo share']:.0%}",
            r["markers"],
            f"{r['within 1 px']:.1%}",
        )
        md.row(*row)
        print("  ".join(row))
    md.end()
    md.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
