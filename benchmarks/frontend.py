"""Accuracy and speed of the stereo front-end on a rendered team and on a real stereo pair.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/frontend.py [--robots 3] [--steps 40]
        [--variant NAME=VALUE[,NAME=VALUE] ...] [--stages]
    OPENBLAS_NUM_THREADS=1 python benchmarks/frontend.py --exact-twin DIR [--correlated]
    OPENBLAS_NUM_THREADS=1 python benchmarks/frontend.py --track-errors DIR

``--stages`` adds where the front-end's CPU time goes: the patch alignments (to a track's first
appearance and left → right, with the image gradients they sample), pyramidal Lucas–Kanade,
the markers, the corners and the NCC row search, in CPU milliseconds per stereo frame and as a
share of the front-end's time (all variants together).

``--track-errors DIR`` measures, in ``DIR/dataset`` and ``DIR/dataset-exact``, how each
track's error against the renderer's truth is correlated in time (lag 1, 5, 10 frames), the
share of it that is a per-track constant, and the error by track age.

``--exact-twin DIR`` takes a rendered team (``DIR/images``, written by
``teamslam.api.simulate_images``) and the dataset the front-end built from it (``DIR/dataset``),
measures the front-end's noise against the renderer's truth, and writes ``DIR/dataset-exact``:
the same tracks and markers with the exact projections plus Gaussian noise of the measured size
— the reference the end-to-end accuracy is compared with.

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
import contextlib
import time

import numpy as np

from teamslam.frontend import FrontendConfig, StereoFrontend, StereoRig, match_stereo
from teamslam.frontend._align import PatchWindow, align_patches, with_gradients
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.config import resolve_frontend
from teamslam.sim.render import T_CAM_BODY, RenderConfig, render_stereo, render_team


def rendered_team(
    robots: int, steps: int, variants: dict[str, FrontendConfig]
) -> tuple[dict, float]:
    """Accuracy and CPU time of each front-end variant on the same rendered frames (the
    variants take turns on every frame, so they share the machine's load); with the rows,
    the CPU seconds of all the front-ends' frames."""
    config = RenderConfig(robots=robots, steps=steps)
    team = render_team(config)
    rig = StereoRig.rectified(config.image_size, config.camera(), T_CAM_BODY)
    stats = {
        name: {
            "counts": [],
            "errors": [],
            "cpu": [],
            "searched": 0,
            "rejected": 0,
            "big_found": [],
            "big_err": [],
            "big_where": [],
            "all_found": [],
            "next_id": 0,
        }
        for name in variants
    }
    for i in range(robots):
        frontends = {
            name: StereoFrontend(rig, cfg, first_id=stats[name]["next_id"])
            for name, cfg in variants.items()
        }
        firsts: dict[str, dict[int, np.ndarray]] = {name: {} for name in variants}
        rng = np.random.default_rng(100 + i)
        for k in range(steps + 1):
            left, right = render_stereo(team.room, team.T_world_cam(i, k), rng)
            ids, z_true, side = team.visible_markers(i, k)
            for name, frontend in frontends.items():
                st, first = stats[name], firsts[name]
                start = time.process_time()
                m = frontend.process(left, right)
                st["cpu"].append(time.process_time() - start)
                new = np.array([int(t) not in first for t in m.track_ids], bool)
                if new.any():
                    pts = team.points_behind(i, k, m.track_uv[new])
                    first.update(zip(m.track_ids[new].tolist(), pts, strict=True))
                st["counts"].append(len(m.feature_ids))
                st["searched"] += m.searched
                st["rejected"] += m.rejected
                if len(m.feature_ids):
                    truth = team.project(i, k, np.array([first[int(t)] for t in m.feature_ids]))
                    st["errors"].append(np.abs(m.features - truth).max(axis=1))
                for mid, zt, s in zip(ids, z_true, side, strict=True):
                    hit = np.flatnonzero(m.object_ids == mid)
                    st["all_found"].append(hit.size > 0)
                    if s >= 25:
                        st["big_found"].append(hit.size > 0)
                        if hit.size:
                            st["big_err"].append(np.abs(m.objects[hit[0]] - zt).max())
                            st["big_where"].append(f"robot {i} frame {k} id {mid} side {s:.0f} px")
        for name, frontend in frontends.items():
            stats[name]["next_id"] = frontend.next_id
    base = 1000 * np.median(stats[next(iter(variants))]["cpu"])
    rows: dict[str, str] = {}
    for name, st in stats.items():
        e = np.concatenate(st["errors"])
        big_err, cpu = st["big_err"], 1000 * np.median(st["cpu"])
        tag = "" if len(variants) == 1 else f"[{name}] "
        rows |= {
            f"{tag}stereo observations per frame": (
                f"{np.mean(st['counts']):.0f} (min {np.min(st['counts'])})"
            ),
            f"{tag}share within 1 px of truth": f"{np.mean(e < 1.0):.2%}",
            f"{tag}median error, px": f"{np.median(e):.3f}",
            f"{tag}stereo matches rejected by the gate": (
                f"{st['rejected'] / max(st['searched'], 1):.1%}"
            ),
            f"{tag}markers ≥ 25 px detected": (
                f"{np.mean(st['big_found']):.1%} of {len(st['big_found'])}"
            ),
            f"{tag}marker centre error median / max, px": (
                f"{np.median(big_err):.2f} / {np.max(big_err):.2f}" if big_err else "-"
            ),
            f"{tag}largest marker centre error at": (
                st["big_where"][int(np.argmax(big_err))] if big_err else "-"
            ),
            f"{tag}markers of any size detected": (
                f"{np.mean(st['all_found']):.1%} of {len(st['all_found'])}"
            ),
            f"{tag}front-end CPU ms per stereo frame (median)": (
                f"{cpu:.0f}" + ("" if len(variants) == 1 else f" (× {cpu / base:.2f})")
            ),
        }
    return rows, float(sum(sum(st["cpu"]) for st in stats.values()))


def warm_up() -> None:
    """Load (or compile) the front-end's compiled kernels, so no frame's time includes it."""
    window = PatchWindow(1)
    image, eye = np.zeros((4, 4), np.float32), np.eye(2)[None]
    template = window.sample(image, np.ones((1, 2)), eye)
    align_patches(window, template, with_gradients(image), np.ones((1, 2)), eye, [[1.0, 0.0]], 1)


@contextlib.contextmanager
def stage_clock():
    """CPU seconds spent in each part of the front-end while the block runs: ``{part: s}``
    (the parts' functions wrapped by a process-time clock, put back afterwards)."""
    from teamslam.frontend import markers, stereo, tracking

    cv2 = require_cv2()
    spent: dict[str, float] = {}
    parts = {
        "patch alignment": [
            (module, name)
            for module in (tracking, stereo)
            for name in ("align_patches", "with_gradients")
        ],
        "Lucas–Kanade": [(cv2, "calcOpticalFlowPyrLK")],
        "markers": [(markers.MarkerDetector, "detect")],
        "corners": [(cv2, "goodFeaturesToTrack"), (cv2, "cornerSubPix")],
        "NCC row search": [(cv2, "matchTemplate"), (cv2, "getRectSubPix")],
    }

    def clocked(part, function):
        def run(*args, **kwargs):
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                spent[part] = spent.get(part, 0.0) + time.process_time() - start

        return run

    saved = [
        (owner, name, getattr(owner, name)) for hooks in parts.values() for owner, name in hooks
    ]
    for part, hooks in parts.items():
        for owner, name in hooks:
            setattr(owner, name, clocked(part, getattr(owner, name)))
    try:
        yield spent
    finally:
        for owner, name, function in saved:
            setattr(owner, name, function)


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


def _fit_correlation(tracks: dict, lags: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Per coordinate ``(κ, φ)`` of the lag correlation ``κ + (1 − κ) φ^lag`` of a track's
    error (least squares over lags 1…``lags``): a per-track constant holding the share ``κ``
    of the variance plus a first-order autoregression with coefficient ``φ``."""
    # without the first sightings: their left coordinates are exact by construction
    tracks = {key: v[1:] for key, v in tracks.items()}
    rho = np.array([_lag_correlation(tracks, lag) for lag in range(1, lags + 1)])  # (L, 4)
    known = np.all(np.isfinite(rho), axis=1)
    rho, lag = rho[known], np.arange(1, lags + 1)[known, None]
    grid = np.linspace(0.0, 0.99, 100)
    kappa, phi = np.zeros(4), np.zeros(4)
    for j in range(4):
        best = np.inf
        for f in grid:
            # for a given φ the model is linear in κ: ρ − φ^l = κ (1 − φ^l)
            x = 1 - f ** lag[:, 0]
            k = float(np.clip(x @ (rho[:, j] - f ** lag[:, 0]) / (x @ x), 0.0, 1.0))
            cost = float(np.sum((rho[:, j] - k - (1 - k) * f ** lag[:, 0]) ** 2))
            if cost < best:
                best, kappa[j], phi[j] = cost, k, f
    return kappa, phi


def _correlated_noise(
    lengths: list[int], sigma: np.ndarray, kappa: np.ndarray, phi: np.ndarray, rng
) -> list[np.ndarray]:
    """Per track of that length ``(length, 4)`` errors: a constant of variance ``κσ²`` plus a
    stationary first-order autoregression of variance ``(1 − κ)σ²`` and coefficient ``φ``."""
    out = []
    for n in lengths:
        constant = np.sqrt(kappa) * sigma * rng.standard_normal(4)
        ar = np.empty((n, 4))
        ar[0] = rng.standard_normal(4)
        for k in range(1, n):
            ar[k] = phi * ar[k - 1] + np.sqrt(1 - phi**2) * rng.standard_normal(4)
        out.append(constant + np.sqrt(1 - kappa) * sigma * ar)
    return out


def exact_twin(directory: str, correlated: bool = False) -> dict:
    """Write ``DIR/dataset-exact``: the exact projections of the front-end's tracks and
    markers plus Gaussian noise of the measured robust σ, white (``correlated=False``) or
    with the measured correlation along a track (``DIR/dataset-exact-correlated``: a
    per-track constant plus a first-order autoregression fitted to the lag-1…10
    correlations, and, as in the front-end's data, no error at a track's first left
    coordinates)."""
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
            err = z - exact
            # a track's first left coordinates define its 3D point: zero by construction,
            # not a measured error
            err[new, :2] = np.nan
            errors.append(err)
            feats.append((ids, exact))
            oids, oz = robot.objects.frame(k)
            pos = team.room.marker_centres[np.searchsorted(team.room.marker_ids, oids)]
            oexact = team.project(i, k, pos.reshape(-1, 3))
            obj_errors.append(oz - oexact)
            objs.append((oids, oexact))
        truths.append((feats, objs))
    e, eo = np.concatenate(errors), np.concatenate(obj_errors)
    # robust σ per coordinate (the outliers are the front-end's, not noise to imitate):
    # 1.4826 · MAD, without the first sightings' left coordinates (zero by construction)
    sigma = 1.4826 * np.nanmedian(np.abs(e - np.nanmedian(e, axis=0)), axis=0)
    sigma_obj = 1.4826 * np.median(np.abs(eo - np.median(eo, axis=0)), axis=0)
    rng = np.random.default_rng(0)
    robots, extra = [], {}
    if correlated:
        kappa, phi = _fit_correlation(_track_errors(team, dataset, dataset))
        extra = {"kappa": kappa.tolist(), "phi": phi.tolist()}
    for robot, (feats, objs) in zip(dataset.robots, truths, strict=True):
        if correlated:
            rows = [ids for ids, _ in feats]
            tracks, index = np.unique(np.concatenate(rows), return_inverse=True)
            lengths = np.bincount(index, minlength=len(tracks))
            noise = _correlated_noise(lengths.tolist(), sigma, kappa, phi, rng)
            age = np.zeros(len(tracks), int)
            f = []
            for ids, z in feats:
                t = np.searchsorted(tracks, ids)
                err = np.array([noise[a][b] for a, b in zip(t, age[t], strict=True)])
                err = err.reshape(-1, 4)
                err[age[t] == 0, :2] = 0.0  # a track's first left coordinates are its point's
                age[t] += 1
                f.append((ids, z + err))
        else:
            f = [(ids, z + sigma * rng.standard_normal(z.shape)) for ids, z in feats]
        o = [(ids, z + sigma_obj * rng.standard_normal(z.shape)) for ids, z in objs]
        robots.append(
            replace(
                robot,
                features=FrameObservations.from_frames(f),
                objects=FrameObservations.from_frames(o),
            )
        )
    name = "dataset-exact-correlated" if correlated else "dataset-exact"
    twin = replace(dataset, robots=robots, name=dataset.name + name.removeprefix("dataset"))
    twin.metadata = {
        **dataset.metadata,
        "exact_twin": {"sigma": sigma.tolist(), "sigma_obj": sigma_obj.tolist(), **extra},
    }
    save_dataset(twin, root / name)
    fitted = {}
    if correlated:
        fitted = {
            "constant share κ of the variance u_l v_l u_r v_r": " ".join(f"{x:.2f}" for x in kappa),
            "autoregression φ u_l v_l u_r v_r": " ".join(f"{x:.2f}" for x in phi),
        }
    return {
        **fitted,
        "feature error robust σ u_l v_l u_r v_r, px": " ".join(f"{x:.3f}" for x in sigma),
        "feature share within 1 px": f"{np.mean(np.nanmax(np.abs(e), axis=1) < 1):.2%}",
        "object error robust σ u_l v_l u_r v_r, px": " ".join(f"{x:.3f}" for x in sigma_obj),
        "written": str(root / name),
    }


def _track_errors(team, dataset, reference) -> dict[tuple[int, int], list]:
    """Per track ``(robot, id)`` its ``(frame, error (4,))`` against the renderer's truth: the
    exact projection of the 3D point behind the track's first sighting in ``reference``."""
    tracks: dict[tuple[int, int], list] = {}
    for i, (robot, ref) in enumerate(zip(dataset.robots, reference.robots, strict=True)):
        first: dict[int, np.ndarray] = {}
        for k in range(robot.frames):
            rids, rz = ref.features.frame(k)
            new = np.array([int(t) not in first for t in rids], bool)
            if new.any():
                first.update(
                    zip(rids[new].tolist(), team.points_behind(i, k, rz[new, :2]), strict=True)
                )
            ids, z = robot.features.frame(k)
            exact = team.project(i, k, np.array([first[int(t)] for t in ids]).reshape(-1, 3))
            for t, e in zip(ids.tolist(), z - exact, strict=True):
                tracks.setdefault((i, t), []).append((k, e))
    return tracks


def _lag_correlation(tracks: dict, lag: int) -> np.ndarray:
    """Correlation per coordinate of a track's error with its error ``lag`` frames later
    (pairs with both errors below 1 px: the outliers are the gate's business)."""
    a, b = [], []
    for v in tracks.values():
        by_frame = dict(v)
        for k, e in v:
            if k + lag in by_frame:
                a.append(e)
                b.append(by_frame[k + lag])
    if len(a) < 3:
        return np.full(4, np.nan)
    a, b = np.array(a), np.array(b)
    good = (np.abs(a).max(axis=1) < 1) & (np.abs(b).max(axis=1) < 1)
    return np.array([np.corrcoef(a[good, j], b[good, j])[0, 1] for j in range(4)])


def track_errors(directory: str) -> dict:
    """How a track's errors are correlated in time, in ``DIR/dataset`` (front-end) and, when
    present, ``DIR/dataset-exact`` (the exact twin, independent noise)."""
    import json
    from pathlib import Path

    from teamslam.datasets import load_dataset

    root = Path(directory)
    cfg = json.loads((root / "images" / "render.json").read_text())
    cfg = {k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}
    team = render_team(RenderConfig(**cfg))
    reference = load_dataset(root / "dataset")
    rows = {}
    for name in ("dataset", "dataset-exact", "dataset-exact-correlated"):
        if not (root / name).is_dir():
            continue
        tracks = _track_errors(team, load_dataset(root / name), reference)
        lengths = np.array([len(v) for v in tracks.values()])
        rows[f"{name}: tracks, mean / max length"] = (
            f"{len(tracks)}, {lengths.mean():.1f} / {lengths.max()}"
        )
        for lag in (1, 5, 10):
            c = _lag_correlation(tracks, lag)
            rows[f"{name}: lag-{lag} correlation u_l v_l u_r v_r"] = " ".join(f"{x:.2f}" for x in c)
        e = np.concatenate([np.array([x for _, x in v]) for v in tracks.values()])
        m = np.concatenate(
            [
                np.repeat(np.mean([x for _, x in v], axis=0)[None], len(v), 0)
                for v in tracks.values()
            ]
        )
        good = np.abs(e).max(axis=1) < 1
        rows[f"{name}: error std u_l v_l u_r v_r, px"] = " ".join(
            f"{x:.3f}" for x in e[good].std(axis=0)
        )
        rows[f"{name}: std of the track means, px"] = " ".join(
            f"{x:.3f}" for x in m[good].std(axis=0)
        )
        for age in (0, 1, 10, 40):
            x = np.array([v[age][1] for v in tracks.values() if len(v) > age])
            if len(x) == 0:
                continue
            g = np.abs(x).max(axis=1) < 1
            rows[f"{name}: rms error at track age {age}, px"] = " ".join(
                f"{y:.3f}" for y in np.sqrt((x[g] ** 2).mean(axis=0))
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--exact-twin", metavar="DIR")
    parser.add_argument("--track-errors", metavar="DIR")
    parser.add_argument(
        "--correlated",
        action="store_true",
        help="with --exact-twin: noise with the front-end's measured correlation along a track",
    )
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME=VALUE[,NAME=VALUE]",
        help="also measure the front-end with these settings, on the same frames (repeatable)",
    )
    parser.add_argument(
        "--stages", action="store_true", help="where the front-end's CPU time goes, by part"
    )
    args = parser.parse_args()
    if args.track_errors:
        for key, value in track_errors(args.track_errors).items():
            print(f"{key:<52}  {value}")
        return
    if args.exact_twin:
        for key, value in exact_twin(args.exact_twin, args.correlated).items():
            print(f"{key:<44}  {value}")
        return
    cv2 = require_cv2()
    cv2.setNumThreads(1)
    variants = {"default": FrontendConfig()}
    for text in args.variant:
        variants[text] = resolve_frontend(text.split(","))[0]
    warm_up()
    with stage_clock() if args.stages else contextlib.nullcontext() as spent:
        rows, total = rendered_team(args.robots, args.steps, variants)
    if spent is not None:
        frames = args.robots * (args.steps + 1) * len(variants)
        for part, seconds in [*spent.items(), ("other", total - sum(spent.values()))]:
            rows[f"CPU per frame: {part}"] = (
                f"{1000 * seconds / frames:.1f} ms ({seconds / total:.0%})"
            )
    rows.update(middlebury())
    width = max(len(k) for k in rows)
    print(f"rendered team: {args.robots} robots × {args.steps + 1} stereo frames, 640×480")
    for key, value in rows.items():
        print(f"{key:<{width}}  {value}")


if __name__ == "__main__":
    main()
