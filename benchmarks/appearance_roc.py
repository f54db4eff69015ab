"""How well each appearance descriptor tells one object from another: ROC AUC on rendered crops.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/appearance_roc.py [--robots 3] [--steps 120]
        [--every 6] [--jitter 0.1] [--street-render DIR [--street-robots 3]
        [--street-steps 420] [--street-seed 17] [--street-every 2] [--absence 10]]
        [--markdown FILE]

Crops come from a function returning :class:`Crops` (images, boxes, truth ids);
:func:`marker_crops` takes them from a rendered team: around every marker wholly visible in a
frame, in the left and in the right image (the right camera has another gain and offset), the
box jittered like a detector's (each side moved by up to ``jitter`` of the box's size); and as
look-alikes boxes of the same sizes on the textured walls away from every marker, each its own
object. Every pair of crops from different images is scored by the descriptors' cosine: a pair
of one marker is *same object*, any other pair *different objects*. The AUC is the chance that
a same-object pair scores above a different-objects pair (0.5: no better than chance).

With ``--street-render DIR``, a second table: the detector team's colour street
(``benchmarks/detector_team.py``'s render, made in ``DIR`` unless it is there), every box the
simulated detector found on a true object in every ``--street-every``-th left image, described
as the tracker receives it. A robot's boxes of one object form a *pass* until the object goes
unboxed for more than ``--absence`` frames (the detector team's ``filter.window``); pairs of one
object from one robot are *one pass* or *across an absence* (another pass: another side of the
object, what re-identification faces), from two robots *another robot*; the negatives are pairs
of two objects of one class (the look-alikes the class leaves to appearance).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import rankdata

from _markdown import Markdown, add_option
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.appearance import DESCRIPTORS, describe, dimension
from teamslam.sim.render import RenderConfig, render_stereo, render_team


@dataclass
class Crops:
    """Boxes in images with the object each shows.

    Attributes
    ----------
    images
        The images (8-bit grey or BGR).
    image
        ``(N,)`` index into ``images`` of each box.
    boxes
        ``(N, 4)`` ``(x_min, y_min, x_max, y_max)`` pixels.
    ids
        ``(N,)`` truth: the object each box shows (equal ids: the same object).
    """

    images: list[np.ndarray]
    image: np.ndarray
    boxes: np.ndarray
    ids: np.ndarray


def jitter_boxes(boxes: np.ndarray, share: float, rng: np.random.Generator) -> np.ndarray:
    """Each side of each box moved by up to ``share`` of the box's width (x) or height (y)."""
    size = np.tile(boxes[:, 2:] - boxes[:, :2], 2)
    return boxes + rng.uniform(-share, share, boxes.shape) * size


def _overlaps(box: np.ndarray, others: np.ndarray) -> bool:
    if not len(others):
        return False
    return bool(
        np.any(
            (box[0] < others[:, 2])
            & (others[:, 0] < box[2])
            & (box[1] < others[:, 3])
            & (others[:, 1] < box[3])
        )
    )


def marker_crops(
    config: RenderConfig, every: int, jitter: float, seed: int = 0, min_side: float = 20.0
) -> Crops:
    """Jittered boxes around the markers of a rendered team (left and right images), and
    wall look-alikes (see the module docstring); markers under ``min_side`` pixels left out."""
    team = render_team(config)
    rng = np.random.default_rng(seed)
    w, h = config.image_size
    room = team.room
    images, image, boxes, ids = [], [], [], []
    look_alike = -1
    for robot in range(config.robots):
        for frame in range(0, config.steps + 1, every):
            left, right = render_stereo(room, team.T_world_cam(robot, frame), rng)
            found, _, side = team.visible_markers(robot, frame)
            found = found[side >= min_side]
            if not found.size:
                continue
            corners = room.marker_corners[np.searchsorted(room.marker_ids, found)]
            z = team.project(robot, frame, corners.reshape(-1, 3)).reshape(-1, 4, 4)
            truth_boxes = []
            for cam, img in ((0, left), (2, right)):
                uv = z[..., cam : cam + 2]
                tight = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
                truth_boxes.append(tight)
                images.append(img)
                image.append(np.full(len(found), len(images) - 1))
                boxes.append(jitter_boxes(tight, jitter, rng))
                ids.append(found)
            # look-alikes: boxes of the markers' sizes on the walls, away from every marker
            taken = np.concatenate(truth_boxes)
            sizes = truth_boxes[0][:, 2:] - truth_boxes[0][:, :2]
            for size in sizes:
                for _ in range(20):
                    corner = rng.uniform([0, 0], [w - 1 - size[0], h - 1 - size[1]])
                    box = np.concatenate([corner, corner + size])
                    centre = (box[None, :2] + box[None, 2:]) / 2
                    on_wall = team.points_behind(robot, frame, centre)[0, 2]
                    if _overlaps(box, taken) or not 0.3 < on_wall < config.room[2] - 0.3:
                        continue
                    images.append(left)
                    image.append(np.array([len(images) - 1]))
                    boxes.append(box[None])
                    ids.append(np.array([look_alike]))
                    look_alike -= 1
                    break
    return Crops(images, np.concatenate(image), np.concatenate(boxes), np.concatenate(ids))


def descriptors(crops: Crops, kind: str) -> np.ndarray:
    """``(N, D)`` descriptors of every crop."""
    out = np.zeros((len(crops.boxes), dimension(kind)), np.float32)
    for i, img in enumerate(crops.images):
        sel = crops.image == i
        if sel.any():
            out[sel] = describe(img, crops.boxes[sel], kind)
    return out


def roc_auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for the ``positive`` labels (Mann–Whitney)."""
    ranks = rankdata(scores)
    n_pos = int(positive.sum())
    n_neg = positive.size - n_pos
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def pair_scores(crops: Crops, vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cosine and same-object truth of every pair of crops from different images."""
    i, j = np.triu_indices(len(crops.boxes), k=1)
    keep = crops.image[i] != crops.image[j]
    i, j = i[keep], j[keep]
    return np.einsum("ij,ij->i", vectors[i], vectors[j]), crops.ids[i] == crops.ids[j]


@dataclass
class StreetBoxes:
    """The simulated detector's boxes on true objects of a rendered street, with their truth.

    Attributes
    ----------
    vectors
        Descriptor kind → ``(N, D)`` descriptors of every box.
    objects, classes, robots, passes
        ``(N,)`` each box's true object, its class, the robot that saw it, and the pass of that
        robot's boxes of the object it belongs to (numbered per robot and object).
    """

    vectors: dict[str, np.ndarray]
    objects: np.ndarray
    classes: np.ndarray
    robots: np.ndarray
    passes: np.ndarray


def street_boxes(directory, every: int, absence: int) -> StreetBoxes:
    """Describe every box on a true object in every ``every``-th colour left image of a rendered
    street (``directory``, written by :func:`teamslam.sim.render.render_team`); a pass ends when
    its object goes unboxed, in every frame, for more than ``absence`` frames."""
    from teamslam.datasets.images import read_detection_truth, read_objects
    from teamslam.frontend.detections import read_detections

    cv2 = require_cv2("the appearance benchmark")
    directory = Path(directory)
    ids, classes, _ = read_objects(directory / "objects.txt")
    class_of = dict(zip(ids.tolist(), classes.tolist(), strict=True))
    vectors: dict[str, list[np.ndarray]] = {kind: [] for kind in DESCRIPTORS}
    objects, robots, passes = [], [], []
    for robot, folder in enumerate(
        sorted(directory.glob("robot_*"), key=lambda p: int(p.name[6:]))
    ):
        names = sorted(p.name for p in (folder / "left").iterdir())
        first = cv2.imread(str(folder / "left" / names[0]), cv2.IMREAD_COLOR)
        size = (first.shape[1], first.shape[0])
        read = read_detections(folder / "detections", names, size)
        truth = read_detection_truth(folder / "detections_truth", names, read)
        last: dict[int, int] = {}
        count: dict[int, int] = {}
        for frame, (name, boxes, found) in enumerate(zip(names, read.images, truth, strict=True)):
            for object_id in np.unique(found[found >= 0]).tolist():
                if object_id in last and frame - last[object_id] > absence:
                    count[object_id] += 1
                count.setdefault(object_id, 0)
                last[object_id] = frame
            keep = found >= 0
            if frame % every or not keep.any():
                continue
            image = cv2.imread(str(folder / "left" / name), cv2.IMREAD_COLOR)
            for kind in DESCRIPTORS:
                # every box of the image, as the tracker receives them (false ones too)
                vectors[kind].append(describe(image, boxes.boxes, kind)[keep])
            objects.append(found[keep])
            robots.append(np.full(int(keep.sum()), robot))
            passes.append(np.array([count[i] for i in found[keep].tolist()]))
    objects_all = np.concatenate(objects)
    return StreetBoxes(
        {kind: np.concatenate(v) for kind, v in vectors.items()},
        objects_all,
        np.array([class_of[i] for i in objects_all.tolist()], np.int64),
        np.concatenate(robots),
        np.concatenate(passes),
    )


def street_pairs(boxes: StreetBoxes) -> dict[str, np.ndarray]:
    """``(N, N)`` masks of the pairs (``i < j``): ``one pass``, ``across an absence``,
    ``another robot`` (one object), ``look-alikes`` (two objects of one class)."""
    n = boxes.objects.size
    upper = np.triu(np.ones((n, n), bool), 1)
    same = boxes.objects[:, None] == boxes.objects[None, :]
    robot = boxes.robots[:, None] == boxes.robots[None, :]
    one_pass = same & robot & (boxes.passes[:, None] == boxes.passes[None, :])
    return {
        "one pass": upper & one_pass,
        "across an absence": upper & same & robot & ~one_pass,
        "another robot": upper & same & ~robot,
        "look-alikes": upper & ~same & (boxes.classes[:, None] == boxes.classes[None, :]),
    }


def _street_table(md: Markdown, args) -> None:
    from detector_team import render_street, street_config

    config = street_config(args.street_robots, args.street_steps, args.street_seed)
    render_street(config, args.street_render)
    boxes = street_boxes(args.street_render, args.street_every, args.absence)
    pairs = street_pairs(boxes)
    kinds = ["one pass", "across an absence", "another robot"]
    counts = {k: int(pairs[k].sum()) for k in pairs}
    title = (
        f"Appearance descriptors, rendered street ({config.image_size[0]}×"
        f"{config.image_size[1]}, colour): one object against look-alikes of its class"
    )
    note = (
        f"{boxes.objects.size} detector boxes on {np.unique(boxes.objects).size} objects from "
        f"{config.robots} robots, one frame in {args.street_every} of {config.steps + 1} "
        f"(street seed {config.seed}); a pass ends after more than {args.absence} frames "
        f"without a box. Pairs of one object: {counts['one pass']} in one pass, "
        f"{counts['across an absence']} across an absence, {counts['another robot']} from "
        f"two robots; against {counts['look-alikes']} pairs of two objects of one class. "
        "AUC of each kind of same-object pair against the look-alike pairs; medians of the "
        "cosine."
    )
    columns = ["descriptor", "dimension", *(f"AUC {k}" for k in kinds)]
    columns += [f"median cos {k}" for k in ("one pass", "across an absence", "look-alikes")]
    rows = []
    for kind in DESCRIPTORS:
        v = boxes.vectors[kind]
        cos = v @ v.T
        negative = cos[pairs["look-alikes"]]
        aucs = []
        for k in kinds:
            positive = cos[pairs[k]]
            scores = np.concatenate([positive, negative])
            truth = np.arange(scores.size) < positive.size
            aucs.append(f"{roc_auc(scores, truth):.3f}")
        medians = [f"{np.median(cos[pairs[k]]):.3f}" for k in ("one pass", "across an absence")] + [
            f"{np.median(negative):.3f}"
        ]
        rows.append([kind, str(dimension(kind)), *aucs, *medians])
    md.table_of(title, columns, rows, note)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=120)
    parser.add_argument("--every", type=int, default=6, help="use every N-th frame")
    parser.add_argument("--jitter", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--street-render",
        type=Path,
        default=None,
        metavar="DIR",
        help="also measure on the detector team's colour street, rendered into (or reused "
        "from) DIR",
    )
    parser.add_argument("--street-seed", type=int, default=17)
    parser.add_argument("--street-steps", type=int, default=420)
    parser.add_argument("--street-robots", type=int, default=3)
    parser.add_argument("--street-every", type=int, default=2, help="use every N-th frame")
    parser.add_argument(
        "--absence", type=int, default=10, help="frames without a box that end a pass"
    )
    add_option(parser)
    args = parser.parse_args(argv)
    md = Markdown(args.markdown)
    require_cv2("the appearance benchmark").setNumThreads(1)
    config = RenderConfig(robots=args.robots, steps=args.steps, seed=args.seed)
    crops = marker_crops(config, args.every, args.jitter, args.seed)
    markers = crops.ids >= 0
    title = (
        f"Appearance descriptors, rendered room ({config.image_size[0]}×"
        f"{config.image_size[1]}, grey): same marker vs different objects"
    )
    note = (
        f"{int(markers.sum())} marker crops ({np.unique(crops.ids[markers]).size} markers, "
        f"left and right images) and {int((~markers).sum())} wall look-alikes from "
        f"{args.robots} robots, every {args.every}th of {args.steps + 1} frames; boxes "
        f"jittered by up to {args.jitter:.0%} of their size per side."
    )
    columns = ["descriptor", "dimension", "ROC AUC", "same: median cos", "different: median cos"]
    md.table(title, columns, note)
    print(title)
    print(note)
    print(f"{'descriptor':<20} {'dim':>4} {'AUC':>7} {'same':>7} {'diff':>7}")
    for kind in DESCRIPTORS:
        scores, same = pair_scores(crops, descriptors(crops, kind))
        auc = roc_auc(scores, same)
        row = (
            kind,
            str(dimension(kind)),
            f"{auc:.3f}",
            f"{np.median(scores[same]):.3f}",
            f"{np.median(scores[~same]):.3f}",
        )
        md.row(*row)
        print(f"{row[0]:<20} {row[1]:>4} {row[2]:>7} {row[3]:>7} {row[4]:>7}")
    md.end()
    md.note(
        "On grey images hue-saturation is zero (no colour): every pair ties, AUC 0.5; "
        "thumbnail+hue-saturation and hue-saturation-or-thumbnail then rank pairs as "
        "thumbnail does."
    )
    if args.street_render is not None:
        _street_table(md, args)
    md.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
