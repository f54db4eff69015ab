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
switches and false objects per 1000 frames, and the association's held and revoked pairs; then
the box centres' errors against the true objects (evaluation only) by box width: their robust
spread as a share of the box, how many lie beyond three σ of the noise model the own run
calibrated (``filter.object_std``, ``filter.object_size_share``), and how much of an object's
error persists from one frame to the next; where the own run's IDF1 is lost, by kind of box
(:func:`_id_losses`); how far a box's appearance lies from its own object's summary within
a pass and after an absence, and how often it is the nearest of its class's after one
(:func:`_appearance_across`); last, each tracker's merges judged by the truth of the boxes, and
the box noise's overconfidence factor it learned (:func:`_merge_rows`).
``--render DIR`` keeps the rendered street in ``DIR`` and renders again only when ``DIR`` does not
hold a finished render of the same configuration (rendering is most of the benchmark's time).
``--markdown FILE`` writes the table headed by the commit,
date, command and machine (``benchmarks/_markdown.py``).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/detector_team.py [--robots 3 --steps 420]
        [--render results/street-render]
"""

from __future__ import annotations

import argparse
import itertools
import json
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam import api
from teamslam.association.appearance import AppearanceModel, cosine_distances, unit_rows
from teamslam.datasets.identity import oracle_object_ids
from teamslam.datasets.images import dataset_from_images, rendered_team_inputs
from teamslam.datasets.stats import robust_std
from teamslam.eval.tracking import identity_map, idf1_losses
from teamslam.msckf.filter.box_noise import box_rows, box_variances
from teamslam.msckf.filter.models import observe
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


def _box_errors(boxes, std: float, share: float) -> tuple[list[list[str]], str]:
    """Rows of the box-error table by quartile of box width, and its note (module docstring).

    Uses the truth: each stereo box centre of a true object against the projection of that
    object's position from the true pose."""
    camera, t_cam_body = boxes.calibration.camera, boxes.calibration.T_cam_body
    positions = dict(zip(boxes.object_ids.tolist(), boxes.object_positions, strict=True))
    rows, normalised, lag = [], [], []
    for robot in boxes.robots:
        d = robot.detections
        frame = np.repeat(np.arange(d.frames), np.diff(d.offsets))
        keep = np.flatnonzero((d.truth >= 0) & np.all(np.isfinite(d.measurements), axis=1))
        pred = np.concatenate(
            [
                observe(camera, t_cam_body, robot.T_world_body[f], positions[o][None])
                for f, o in zip(frame[keep].tolist(), d.truth[keep].tolist(), strict=True)
            ]
        )
        row = box_rows(
            d.measurements[keep], d.sizes[keep], boxes.calibration.image_size, std, share
        )
        e = (row[:, :4] - pred) / np.sqrt(box_variances(row, std, share))
        rows.append(np.column_stack([row, row[:, :4] - pred]))
        normalised.append(e)
        # the same object's uncut box in consecutive frames: how much of the error persists
        last: dict[int, tuple[int, np.ndarray]] = {}
        cuts = row[:, 6:10].any(axis=1)
        for f, o, err, cut in zip(frame[keep], d.truth[keep], e, cuts, strict=True):
            if not cut and o in last and last[o][0] == f - 1:
                lag.append((last[o][1], err))
            last[o] = (f, err) if not cut else (-2, err)
    table = np.concatenate(rows)
    e = np.concatenate(normalised)
    cut = table[:, 6:10].any(axis=1)
    width = table[:, 4]
    edges = np.quantile(width[~cut], [0.0, 0.25, 0.5, 0.75, 1.0])
    out = []
    for lo, hi in itertools.pairwise(edges):
        m = ~cut & (width >= lo) & (width <= hi)
        r = table[m, 10:]
        out.append(
            [
                f"{lo:.0f}–{hi:.0f}",
                str(int(m.sum())),
                f"{robust_std(r[:, 0]) / np.median(table[m, 4]):.3f}",
                f"{robust_std(r[:, 1]) / np.median(table[m, 5]):.3f}",
                f"{np.median(np.abs(r[:, :2])):.2f}",
                f"{np.mean(np.abs(e[m, 0]) > 3):.3f}",
                f"{np.mean(np.abs(e[m, 1]) > 3):.3f}",
            ]
        )
    pairs = np.array(lag)
    clipped = np.clip(pairs, -5.0, 5.0)  # the persistent part, not a few absurd boxes

    def persist(c: int) -> float:
        return float(np.corrcoef(clipped[:, 0, c], clipped[:, 1, c])[0, 1])

    note = (
        f"{table.shape[0]} stereo boxes of true objects, {int(cut.sum())} cut by the image "
        f"border (not in the rows; their u beyond 3σ: {np.mean(np.abs(e[cut, 0]) > 3):.3f}); "
        f"noise model of the own run: σ₀ = {std:.3g} px, share α = {share:.3g}; "
        f"correlation of an object's normalised error in consecutive frames: u_l "
        f"{persist(0):.2f}, v_l {persist(1):.2f} ({pairs.shape[0]} pairs)."
    )
    return out, note


def _id_losses(boxes, hypotheses, std: float, share: float) -> tuple[list[list[str]], str]:
    """Rows of where IDF1 is lost, by kind of box, and their note (evaluation only).

    Each box of a true object is of one kind, the first that applies: *left image only* (no
    right centre), *cut* by the image border (any clipped coordinate of
    :func:`~teamslam.msckf.filter.box_noise.box_rows` under the run's noise), *large* (uncut,
    at least the upper quartile of the uncut stereo boxes' widths), *other*. Per kind: the
    boxes, those named with an id other than their object's under IDF1's one-to-one map
    (``wrong``, each costing IDF1's sum ``GT + H − 2·IDTP`` two), those left unnamed (one) and
    the kind's share of that sum; the note splits the wrong ids into revisits and the rest
    (:func:`~teamslam.eval.tracking.idf1_losses`), and the revisits into a second id of the
    box's own object and an id of another (:func:`_named_anew`)."""
    kinds = ("left image only", "cut", "large", "other")
    counts = np.zeros((len(kinds), 3), np.int64)
    widths, per_robot = [], []
    for robot, hyp in zip(boxes.robots, hypotheses, strict=True):
        d = robot.detections
        hyp = np.asarray(hyp, np.int64)
        row = box_rows(d.measurements, d.sizes, boxes.calibration.image_size, std, share)
        mono = ~np.isfinite(d.measurements[:, 2])
        cut = row[:, 6:10].any(axis=1) & ~mono
        widths.append(d.sizes[~mono & ~cut, 0])
        per_robot.append((d, hyp, mono, cut))
    large_from = float(np.quantile(np.concatenate(widths), 0.75))
    revisit = within = anew = 0
    for d, hyp, mono, cut in per_robot:
        real = d.truth >= 0
        wrong = real & (hyp >= 0) & (identity_map(d.truth, hyp) != hyp)
        unnamed = real & (hyp < 0)
        large = ~mono & ~cut & (d.sizes[:, 0] >= large_from)
        for k, mask in enumerate((mono, cut, large, ~mono & ~cut & ~large)):
            counts[k] += [(real & mask).sum(), (wrong & mask).sum(), (unnamed & mask).sum()]
        losses = idf1_losses(d.offsets, d.truth, hyp, revisit_gap=10)
        anew += _named_anew(d.offsets, d.truth, hyp, revisit_gap=10)
        revisit += losses["wrong_revisit"]
        within += losses["wrong_within_pass"] + losses["wrong_unmapped"]
    total = int(2 * counts[:, 1].sum() + counts[:, 2].sum())
    rows = [
        [
            name,
            str(c[0]),
            str(c[1]),
            str(c[2]),
            f"{(2 * c[1] + c[2]) / max(total, 1):.2f}",
        ]
        for name, c in zip(kinds, counts, strict=True)
    ]
    note = (
        f"own run (tracking + association, appearance); large: uncut stereo boxes at least "
        f"{large_from:.0f} px wide; IDF1's loss GT + H − 2·IDTP = {total} (false boxes named "
        f"aside); of the {int(counts[:, 1].sum())} wrong ids {revisit} came after an absence of "
        f"more than `filter.window` frames ({anew} of them under a second id of their own "
        f"object, the revisit named anew and never merged; {revisit - anew} under an id of "
        f"another object), {within} within a pass."
    )
    return rows, note


def _named_anew(offsets, truth, hyp, revisit_gap: int) -> int:
    """Of one robot's wrong ids after an absence (:func:`~teamslam.eval.tracking.idf1_losses`),
    those under an id most of whose true boxes are of the box's own object: a second id of the
    object, not another object's (evaluation only)."""
    frame = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    real = truth >= 0
    mapped = identity_map(truth, hyp)
    majority = {}
    for i in np.unique(hyp[real & (hyp >= 0)]).tolist():
        objects, counts = np.unique(truth[real & (hyp == i)], return_counts=True)
        majority[i] = int(objects[np.argmax(counts)])
    out = 0
    for k in np.flatnonzero(real & (hyp >= 0) & (mapped != hyp) & (mapped >= 0)).tolist():
        own = frame[(hyp == mapped[k]) & (truth == truth[k])]
        if np.min(np.abs(own - frame[k])) > revisit_gap and majority[int(hyp[k])] == truth[k]:
            out += 1
    return out


def _appearance_across(boxes, gap: int, first: int = 6) -> tuple[list[list[str]], str]:
    """Rows of how far a box's descriptor lies from its own object's summary within a pass and
    after an absence, against other objects', and their note (evaluation only: the truth of
    every box).

    Per robot, frame by frame, each box of a true object against: the mean of the unit
    descriptors of its object's earlier boxes in the current pass (*same, within a pass*);
    the mean of its object's boxes before the last absence of more than ``gap`` frames (*same,
    after an absence*: what re-identification compares); the mean of every other object's boxes
    so far (*different*). Cosine distances and the ROC AUC of each *same* against *different*
    (:class:`~teamslam.association.appearance.AppearanceModel`, the tracker's binning). The
    note: of the passes after an absence with at least ``first`` boxes, in how many the mean
    distance of those boxes to their object's earlier summary is the least among the objects
    of its class seen before (appearance alone naming the revisit among its look-alikes)."""
    within, across, different = [], [], []
    passes = nearest = 0
    for robot in boxes.robots:
        d = robot.detections
        unit = unit_rows(d.appearance)
        sums: dict[int, np.ndarray] = {}  # every box so far
        current: dict[int, np.ndarray] = {}  # the current pass's boxes
        before: dict[int, np.ndarray] = {}  # the boxes before the last absence
        last: dict[int, int] = {}
        label: dict[int, int] = {}
        # per pass after an absence: its class's objects seen before, their means, its boxes
        pending: dict[int, tuple[list[int], np.ndarray, list[np.ndarray]]] = {}
        for f in range(d.offsets.size - 1):
            rows = np.arange(d.offsets[f], d.offsets[f + 1])
            rows = rows[(d.truth[rows] >= 0) & unit[rows].any(axis=1)]
            # every object seen before this frame, its summary and its class
            seen = np.array(list(sums), np.int64)
            means = unit_rows(np.array([sums[o] for o in seen.tolist()]).reshape(-1, unit.shape[1]))
            classes = np.array([label[o] for o in seen.tolist()], np.int64)
            for j in rows.tolist():
                t = int(d.truth[j])
                if t in last and f - last[t] > gap:
                    before[t] = sums[t].copy()
                    del current[t]
                    of_class = (seen == t) | (classes == d.classes[j])
                    pending[t] = (seen[of_class].tolist(), means[of_class], [])
                if t in current:
                    within.append(cosine_distances(current[t][None], unit[j][None])[0, 0])
                if t in before:
                    across.append(cosine_distances(before[t][None], unit[j][None])[0, 0])
                different.extend(cosine_distances(means[seen != t], unit[j][None])[:, 0].tolist())
                if t in pending:
                    candidates, held, views = pending[t]
                    views.append(unit[j])
                    if len(views) == first:
                        del pending[t]
                        passes += 1
                        mean_distance = cosine_distances(held, np.array(views)).mean(axis=1)
                        nearest += int(candidates[int(np.argmin(mean_distance))] == t)
            for j in rows.tolist():
                t = int(d.truth[j])
                sums[t] = sums.get(t, 0.0) + unit[j]
                current[t] = current.get(t, 0.0) + unit[j]
                last[t] = f
                label[t] = int(d.classes[j])
    rows = []
    for name, same in (("within a pass", within), (f"after an absence (> {gap} frames)", across)):
        model = AppearanceModel(0.99)
        model.add(np.array(same), np.array(different))
        rows.append(
            [
                name,
                str(len(same)),
                f"{np.median(same):.3f}",
                f"{np.median(different):.3f}",
                f"{model.auc():.3f}",
            ]
        )
    note = (
        f"{len(different)} *different* samples, median cosine distance {np.median(different):.3f}; "
        f"of {passes} passes after an absence with at least {first} boxes, in {nearest} "
        f"({nearest / max(passes, 1):.2f}) their first {first} boxes lie nearest, on average, "
        "to their own object's earlier summary among the objects of its class seen before."
    )
    return rows, note


def _merge_rows(runs: list[tuple[str, api.Run]]) -> list[list[str]]:
    """Per own run, filter and robot its tracker's merges judged by the truth of the boxes
    (:func:`~teamslam.eval.tracking.merge_audit`) and the box noise's overconfidence factor."""
    rows = []
    for (name, run), mode in itertools.product(runs, ("separate", "consensus")):
        robots = (run.by_mode[mode].get("tracking") or {}).get("robots", [])
        for k, entry in enumerate(robots):
            if not entry or "merges" not in entry:
                continue
            a = entry["merges"]
            rows.append(
                [
                    f"{name}, {mode}, robot {k}",
                    str(a["merges"]),
                    str(a["right"]),
                    str(a["wrong"]),
                    f"{a['passes']} | {a['passes_wrong']}",
                    str(a["largest_pass"]),
                    f"{entry['object_overconfidence']:.0f}",
                    f"{entry['idf1']:.3f}",
                ]
            )
    return rows


def street_config(robots: int, steps: int, seed: int) -> RenderConfig:
    """The street this benchmark renders (``--objects shapes --layout street --no-markers``)."""
    return RenderConfig(
        robots=robots,
        steps=steps,
        seed=seed,
        layout="street",
        objects="shapes",
        markers_per_wall=0,
    )


def render_street(config: RenderConfig, directory: Path) -> None:
    """Render the street into ``directory`` unless it holds a finished render of ``config``
    (its ``render.json`` equal to ``config``'s, and a ``done`` mark written after rendering)."""
    stored = directory / "render.json"
    if (directory / "done").exists() and stored.exists():
        written = json.loads(json.dumps(asdict(config)))  # tuples as lists, as on disk
        if json.loads(stored.read_text()) == written:
            return
        raise SystemExit(f"{directory} holds a render of another configuration")
    render_team(config, directory, detector=DetectorConfig())
    (directory / "done").write_text("rendered\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=420)
    parser.add_argument("--seed", type=int, default=17)
    parser.add_argument(
        "--render",
        type=Path,
        default=None,
        help="keep the rendered street in DIR and reuse it (default: a temporary directory)",
    )
    add_option(parser)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        render = args.render if args.render is not None else Path(tmp) / "street"
        config = street_config(args.robots, args.steps, args.seed)
        render_street(config, render)
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
    md.table_of(
        "Objects from a detector: a rendered street, own ids against the oracle's",
        header,
        rows,
        note,
    )
    noise = own.by_mode["consensus"]["config"]["filter"]
    error_rows, error_note = _box_errors(
        boxes, float(noise["object_std"]), float(noise["object_size_share"])
    )
    error_header = [
        "box width [px]",
        "boxes",
        "robust σ(u_l) / width",
        "robust σ(v_l) / height",
        "median abs error [px]",
        "u_l beyond 3σ",
        "v_l beyond 3σ",
    ]
    md.table_of(
        "Box-centre errors against the true objects, by box width",
        error_header,
        error_rows,
        error_note,
    )
    loss_rows, loss_note = _id_losses(
        boxes,
        own.results["consensus"].extra["tracking_hypotheses"],
        float(noise["object_std"]),
        float(noise["object_size_share"]),
    )
    loss_header = ["boxes", "of true objects", "wrong id", "unnamed", "share of IDF1's loss"]
    md.table_of(
        "Where the own run's IDF1 is lost, by kind of box", loss_header, loss_rows, loss_note
    )
    across_rows, across_note = _appearance_across(boxes, settings["filter.window"])
    md.table_of(
        "A box against its own object's appearance summary, within a pass and after an absence",
        ["same object", "boxes", "median distance", "different: median", "ROC AUC"],
        across_rows,
        across_note,
    )
    merge_header = [
        "run, filter, robot",
        "merges",
        "right",
        "wrong",
        "passes | wrong",
        "largest pass",
        "κ at the end",
        "IDF1",
    ]
    md.table_of(
        "The trackers' merges, judged by the truth of the boxes",
        merge_header,
        _merge_rows([("own", own)]),
        "merges: loop closures and re-identifications, each judged by the boxes the two objects "
        "took under their own ids (the old one's up to the new one's first; unjudged ones "
        "counted in merges only); a pass: the merges into one old object of boxes of one true "
        "object (a revisit named anew and merged again and again); κ: the factor by which the "
        "run found the calibrated box noise too small (`filter.object_overconfidence`). "
        "Without appearance nothing is re-identified by boxes: no merges.",
    )
    md.write()


if __name__ == "__main__":
    main()
