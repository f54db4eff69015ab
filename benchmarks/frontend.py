"""Accuracy and speed of the stereo front-end on a rendered team and on a real stereo pair.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/frontend.py [--robots 3] [--steps 40]
    OPENBLAS_NUM_THREADS=1 python benchmarks/frontend.py --exact-twin DIR

``--exact-twin DIR`` takes a rendered team (``DIR/images``, written by ``simulate_images``)
and the dataset the front-end built from it (``DIR/dataset``), measures the front-end's noise
against the renderer's truth, and writes ``DIR/dataset-exact``: the same tracks and markers
with the exact projections plus Gaussian noise of the measured size — the reference the
end-to-end accuracy is compared with.

Rendered team (vignetting, right-camera gain and offset, sensor noise, JPEG at quality 75):
stereo observations per frame; the share of observations within 1 px of the truth in all four
coordinates, the truth being the exact projection of the 3D point behind the track's first
sighting (so tracking drift counts); marker detection for markers of at least 25 px (shortest
projected side in both images) and over all sizes, with the centre error; the share the
stereo gate rejected; CPU milliseconds of the front-end per stereo frame (process time, one
thread). Middlebury ``stereo_motorcycle`` (scikit-image, if installed): the share of accepted
matches within 1 px of the ground-truth disparity and the rejected share.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from teamslam.frontend import FrontendConfig, StereoFrontend, StereoRig, match_stereo
from teamslam.frontend._cv import require_cv2
from teamslam.sim.render import T_CAM_BODY, RenderConfig, render_stereo, render_team


def rendered_team(robots: int, steps: int) -> dict:
    config = RenderConfig(robots=robots, steps=steps)
    team = render_team(config)
    camera = config.camera()
    rig = StereoRig(
        config.image_size,
        camera.intrinsics,
        camera.intrinsics,
        np.zeros(5),
        np.zeros(5),
        camera.T_left_right,
        T_CAM_BODY,
    )
    counts, errors, cpu, searched, rejected = [], [], [], 0, 0
    big_found, big_err, all_found = [], [], []
    next_id = 0
    for i in range(robots):
        frontend = StereoFrontend(rig, FrontendConfig(), first_id=next_id)
        rng = np.random.default_rng(100 + i)
        first: dict[int, np.ndarray] = {}
        for k in range(steps + 1):
            left, right = render_stereo(team.room, team.T_world_cam(i, k), rng)
            start = time.process_time()
            m = frontend.process(left, right)
            cpu.append(time.process_time() - start)
            new = np.array([int(t) not in first for t in m.track_ids], bool)
            if new.any():
                pts = team.points_behind(i, k, m.track_uv[new])
                first.update(zip(m.track_ids[new].tolist(), pts, strict=True))
            counts.append(len(m.feature_ids))
            searched += m.searched
            rejected += m.rejected
            if len(m.feature_ids):
                truth = team.project(i, k, np.array([first[int(t)] for t in m.feature_ids]))
                errors.append(np.abs(m.features - truth).max(axis=1))
            ids, z_true, side = team.visible_markers(i, k)
            for mid, zt, s in zip(ids, z_true, side, strict=True):
                hit = np.flatnonzero(m.object_ids == mid)
                all_found.append(hit.size > 0)
                if s >= 25:
                    big_found.append(hit.size > 0)
                    if hit.size:
                        big_err.append(np.abs(m.objects[hit[0]] - zt).max())
        next_id = frontend.next_id
    e = np.concatenate(errors)
    return {
        "stereo observations per frame": f"{np.mean(counts):.0f} (min {np.min(counts)})",
        "share within 1 px of truth": f"{np.mean(e < 1.0):.2%}",
        "median error, px": f"{np.median(e):.3f}",
        "stereo matches rejected by the gate": f"{rejected / max(searched, 1):.1%}",
        "markers ≥ 25 px detected": f"{np.mean(big_found):.1%} of {len(big_found)}",
        "marker centre error median / max, px": (
            f"{np.median(big_err):.2f} / {np.max(big_err):.2f}" if big_err else "-"
        ),
        "markers of any size detected": f"{np.mean(all_found):.1%} of {len(all_found)}",
        "front-end CPU ms per stereo frame (median)": f"{1000 * np.median(cpu):.0f}",
    }


def middlebury() -> dict:
    try:
        from skimage.data import stereo_motorcycle
    except ImportError:
        return {"Middlebury": "scikit-image not installed (pip install teamslam[bench])"}
    cv2 = require_cv2()
    left, right, disparity = stereo_motorcycle()
    left = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
    right = cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
    known = np.isfinite(disparity)
    d_range = (float(disparity[known].min()) - 2, float(disparity[known].max()) + 2)
    corners = cv2.goodFeaturesToTrack(left, 2000, 0.005, 5).reshape(-1, 2).astype(float)
    cols, rows = np.rint(corners).astype(int).T
    truth = disparity[rows, cols]
    corners, truth = corners[np.isfinite(truth)], truth[np.isfinite(truth)]
    m = match_stereo(left, right, corners, d_range, FrontendConfig())
    d = corners[m.accepted, 0] - m.uv_right[m.accepted, 0]
    err = np.abs(d - truth[m.accepted])
    return {
        "Middlebury points with known disparity": str(len(corners)),
        "Middlebury accepted within 1 px": f"{np.mean(err < 1):.1%}",
        "Middlebury accepted off by > 3 px": f"{np.mean(err > 3):.1%}",
        "Middlebury rejected share": f"{1 - m.accepted[m.searched].mean():.1%}",
    }


def exact_twin(directory: str) -> dict:
    import json
    from dataclasses import replace
    from pathlib import Path

    from teamslam.datasets import FrameObservations, load_dataset, save_dataset

    root = Path(directory)
    cfg = json.loads((root / "images" / "render.json").read_text())
    cfg = {k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}
    team = render_team(RenderConfig(**cfg))
    dataset = load_dataset(root / "dataset")
    truths, errors, obj_errors = [], [], []
    for i, robot in enumerate(dataset.robots):
        first: dict[int, np.ndarray] = {}
        feats, objs = [], []
        for k in range(robot.frames):
            ids, z = robot.features.frame(k)
            new = np.array([int(t) not in first for t in ids], bool)
            if new.any():
                first.update(
                    zip(ids[new].tolist(), team.points_behind(i, k, z[new, :2]), strict=True)
                )
            exact = team.project(i, k, np.array([first[int(t)] for t in ids]).reshape(-1, 3))
            errors.append(z - exact)
            feats.append((ids, exact))
            oids, oz = robot.objects.frame(k)
            pos = team.room.marker_centres[np.searchsorted(team.room.marker_ids, oids)]
            oexact = team.project(i, k, pos.reshape(-1, 3))
            obj_errors.append(oz - oexact)
            objs.append((oids, oexact))
        truths.append((feats, objs))
    e, eo = np.concatenate(errors), np.concatenate(obj_errors)
    # robust σ (the outliers are the front-end's, not noise to imitate): 1.4826 · MAD
    sigma = float(1.4826 * np.median(np.abs(e - np.median(e, axis=0))))
    sigma_obj = float(1.4826 * np.median(np.abs(eo - np.median(eo, axis=0))))
    rng = np.random.default_rng(0)
    robots = []
    for robot, (feats, objs) in zip(dataset.robots, truths, strict=True):
        f = [(ids, z + sigma * rng.standard_normal(z.shape)) for ids, z in feats]
        o = [(ids, z + sigma_obj * rng.standard_normal(z.shape)) for ids, z in objs]
        robots.append(
            replace(
                robot,
                features=FrameObservations.from_frames(f),
                objects=FrameObservations.from_frames(o),
            )
        )
    twin = replace(dataset, robots=robots, name=dataset.name + "-exact")
    twin.metadata = {**dataset.metadata, "exact_twin": {"sigma": sigma, "sigma_obj": sigma_obj}}
    save_dataset(twin, root / "dataset-exact")
    return {
        "feature error robust σ, px": f"{sigma:.3f}",
        "feature share within 1 px": f"{np.mean(np.abs(e).max(axis=1) < 1):.2%}",
        "object error robust σ, px": f"{sigma_obj:.3f}",
        "written": str(root / "dataset-exact"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--exact-twin", metavar="DIR")
    args = parser.parse_args()
    if args.exact_twin:
        for key, value in exact_twin(args.exact_twin).items():
            print(f"{key:<32}  {value}")
        return
    rows = rendered_team(args.robots, args.steps)
    rows.update(middlebury())
    width = max(len(k) for k in rows)
    print(f"rendered team: {args.robots} robots × {args.steps + 1} stereo frames, 640×480")
    for key, value in rows.items():
        print(f"{key:<{width}}  {value}")


if __name__ == "__main__":
    main()
