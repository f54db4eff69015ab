"""Rendering with objects, and what the simulated detector's boxes look like.

Run on demand: ``OPENBLAS_NUM_THREADS=1 python benchmarks/render_objects.py [--markdown FILE]``.

``speed``: seconds per stereo frame (left and right albedo, image effects, JPEG) of the room
without objects, the room and the street with objects, and the street with the id buffers and
the detector on both images; process CPU time (what one core spends, whatever the machine's
load) and wall time, medians over frames spread along robot 0's path, at the default image size.
``boxes``: the default detector on a default team in the street (every ``--every``-th frame of
every robot): boxes per image, the share of false boxes, and how the objects a detector could
see turned into boxes.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from _markdown import Markdown, add_option
from teamslam.sim.detector import DetectorConfig, detect
from teamslam.sim.render import RenderConfig, render_stereo, render_team
from teamslam.sim.shapes import SHAPE_CLASSES

SCENES = {
    "room, no objects": {},
    "room, objects": {"objects": "shapes"},
    "street, objects": {"layout": "street", "objects": "shapes"},
}


def _speed(frames: int, md: Markdown) -> None:
    md.table(
        "Seconds per stereo frame (640×480, one core)",
        ["scene", "CPU median (s)", "wall median (s)", "objects"],
        note=f"{frames} frames of robot 0 spread along its path, the scenes taken in turn at "
        "each frame (so that other work on the machine weighs on all alike); left and right "
        "images with every image effect.",
    )
    detector = DetectorConfig()
    names = [*SCENES, "street, objects, ids + detector"]
    teams = [render_team(RenderConfig(**SCENES.get(n, SCENES["street, objects"]))) for n in names]
    cpu = {n: [] for n in names}
    wall = {n: [] for n in names}
    rng = np.random.default_rng(0)
    for k in np.linspace(0, teams[0].config.steps, frames).astype(int):
        for name, team in zip(names, teams, strict=True):
            with_detector = name not in SCENES
            T = team.T_world_cam(0, k)
            c0, w0 = time.process_time(), time.perf_counter()
            out = render_stereo(team.room, T, rng, ids=with_detector)
            if with_detector:
                for side in (0, 1):
                    detect(detector, out[2 + side], out[4 + side], team.room.shapes.classes, 5, rng)
            cpu[name].append(time.process_time() - c0)
            wall[name].append(time.perf_counter() - w0)
    print(f"{'scene':<34} {'CPU s':>8} {'wall s':>8} {'objects':>8}")
    for name, team in zip(names, teams, strict=True):
        row = (name, f"{statistics.median(cpu[name]):.3f}", f"{statistics.median(wall[name]):.3f}")
        print(f"{row[0]:<34} {row[1]:>8} {row[2]:>8} {len(team.room.shapes):>8}")
        md.row(*row, str(len(team.room.shapes)))
    md.end()


def _boxes(robots: int, steps: int, every: int, md: Markdown) -> None:
    config = RenderConfig(robots=robots, steps=steps, layout="street", objects="shapes")
    detector = DetectorConfig()
    team = render_team(config)
    shapes = team.room.shapes
    K, size = config.camera().intrinsics, config.image_size
    camera = config.camera()
    boxes, true, eligible, confused, in_view = [], [], [], [], []
    seen = np.zeros((robots, len(shapes)), bool)
    unseen = steps + 1
    first = np.full((robots, len(shapes)), unseen)  # the frame a robot first detects an object
    offsets = {True: [], False: []}  # whole and inside the image: the box centre's offset
    for r in range(robots):
        rng = np.random.default_rng([r, 33])
        for k in range(0, steps + 1, every):
            T = team.T_world_cam(r, k)
            for T_cam in (T, T @ camera.T_left_right):
                _, ids, silhouette = team.room.render_ids(T_cam, K, size)
                out = detect(detector, ids, silhouette, shapes.classes, len(SHAPE_CLASSES), rng)
                _centre_offsets(ids, silhouette, out.eligible, shapes.centres, T_cam, K, offsets)
                real = out.truth >= 0
                boxes.append(len(out.truth))
                true.append(int(real.sum()))
                eligible.append(len(out.eligible))
                in_view.append(len(np.unique(ids[ids >= 0])))
                confused.append(
                    int(np.sum(out.detections.classes[real] != shapes.classes[out.truth[real]]))
                )
                seen[r, out.truth[real]] = True
                first[r, out.truth[real]] = np.minimum(first[r, out.truth[real]], k)
    boxes, true, eligible = np.array(boxes), np.array(true), np.array(eligible)
    images = len(boxes)
    false_share = (boxes - true).sum() / max(boxes.sum(), 1)
    rows = [
        ("images (left and right)", f"{images}"),
        ("objects in the street", f"{len(shapes)}"),
        ("objects showing at least one pixel, per image (mean)", f"{np.mean(in_view):.2f}"),
        ("objects visible enough to detect, per image (mean)", f"{eligible.mean():.2f}"),
        ("boxes per image: mean", f"{boxes.mean():.2f}"),
        ("boxes per image: median / max", f"{np.median(boxes):.0f} / {boxes.max()}"),
        ("true boxes per image (mean)", f"{true.mean():.2f}"),
        ("images without a box", f"{np.mean(boxes == 0):.1%}"),
        ("share of false boxes", f"{false_share:.1%}"),
        ("missed (of the detectable)", f"{1 - true.sum() / max(eligible.sum(), 1):.1%}"),
        ("true boxes with a wrong class", f"{sum(confused) / max(true.sum(), 1):.1%}"),
        ("objects detected by one robot only", f"{np.mean(seen.sum(axis=0) == 1):.1%}"),
        ("objects detected by every robot", f"{np.mean(seen.all(axis=0)):.1%}"),
    ]
    lead = []  # per robot and object it detects: how long before another robot detected it
    for r in range(robots):
        others = np.delete(first, r, axis=0).min(axis=0)
        mine = first[r] < unseen
        lead.append(np.where(others[mine] < unseen, first[r][mine] - others[mine], -1))
    lead = np.concatenate(lead) / config.rate
    earlier = lead > 0
    rows += [
        ("a robot's objects another robot detected before it", f"{earlier.mean():.1%}"),
        (
            "  how long before (s): median / max",
            f"{np.median(lead[earlier]):.1f} / {lead[earlier].max():.1f}" if earlier.any() else "-",
        ),
    ]
    for whole in (True, False):
        off = np.abs(np.reshape(offsets[whole], (-1, 2)))
        which = "whole objects" if whole else "occluded or cut by the border"
        for axis, name in ((0, "u"), (1, "v")):
            q50, q90 = np.quantile(off[:, axis], [0.5, 0.9])
            rows.append(
                (
                    f"box centre − image of the reference point, {name} / box size, {which} "
                    f"({len(off)}): median / 90 %",
                    f"{q50:.1%} / {q90:.1%}",
                )
            )
    md.table(
        f"The default detector in the street ({robots} robots, {steps} steps, every {every}th "
        "frame)",
        ["quantity", "value"],
        note=f"Detector settings: {detector}.",
    )
    for name, value in rows:
        print(f"{name:<56} {value:>12}")
        md.row(name, value)
    md.end()


def _centre_offsets(ids, silhouette, eligible, centres, T_world_cam, K, offsets) -> None:
    """Per detectable object, the offset of its noise-free box's centre from the image of its
    reference point, as shares of the box's width and height; filed under whole objects (all of
    the silhouette visible, the box inside the image) or the others."""
    from scipy import ndimage

    h, w = ids.shape
    extents = ndimage.find_objects(ids + 1, max_label=len(silhouette))
    counts = np.bincount(ids[ids >= 0], minlength=len(silhouette))
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    for j in eligible:
        rows, cols = extents[j]
        box = np.array([cols.start, rows.start, cols.stop, rows.stop], float) - 0.5
        p = (centres[j] - o) @ R
        uv = (K @ p)[:2] / p[2]
        size = box[2:] - box[:2]
        inside = box[0] > 0 and box[1] > 0 and box[2] < w - 1 and box[3] < h - 1
        whole = bool(inside and counts[j] == silhouette[j])
        offsets[whole].append((0.5 * (box[:2] + box[2:]) - uv) / size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=("speed", "boxes"), default=["speed", "boxes"])
    parser.add_argument("--frames", type=int, default=30, help="speed: frames per scene")
    parser.add_argument("--robots", type=int, default=3, help="boxes: robots")
    parser.add_argument("--steps", type=int, default=200, help="boxes: steps per robot")
    parser.add_argument("--every", type=int, default=2, help="boxes: every n-th frame")
    add_option(parser)
    args = parser.parse_args()
    md = Markdown(args.markdown)
    what = args.only
    if "speed" in what:
        _speed(args.frames, md)
    if "boxes" in what:
        _boxes(args.robots, args.steps, args.every, md)
    md.write()


if __name__ == "__main__":
    main()
