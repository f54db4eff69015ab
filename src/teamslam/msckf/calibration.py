"""Self-calibration of a team's sensor model from its data alone (no ground truth).

:func:`calibrate` estimates the odometry noise per step and the measurement σ of geometric
features and object box centres: a filter-free start above the epipolar lower bound
(:func:`epipolar_noise`), then filter passes of every robot alone until no σ moves by more than
``tolerance`` — measurement σ by covariance matching of the innovations (:func:`nis_ratio`),
odometry σ by expectation–maximisation over the smoothed window (every lag, non-negative least
squares). Object detections with a box size get a σ that grows with the box
(:mod:`teamslam.msckf.filter.box_noise`): its floor and share are fitted to the noise the
innovations show at each box size (:func:`box_noise_fit`; the floor at least the pixel grid's,
:data:`BOX_QUANTIZATION_STD`, for boxes on images of known size), from a filter-free start of
the same form (:func:`epipolar_box_noise`). The object depth range is not estimated. Derivation and
references: the concept page *Calibration* (``docs/concepts/calibration.md``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from teamslam.datasets.model import TeamDataset
from teamslam.datasets.sensor_model import SensorModel, SensorNoise
from teamslam.datasets.stats import robust_std
from teamslam.errors import InputError
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.filter.update import stereo_point
from teamslam.msckf.settings.health import SENSORS, InnovationRecord, SensorHealth
from teamslam.msckf.settings.values import MsckfConfig

__all__ = [
    "BOX_QUANTIZATION_STD",
    "CalibrationResult",
    "box_noise_fit",
    "box_quantization_std",
    "calibrate",
    "calibration_json",
    "calibration_table",
    "default_frames",
    "epipolar_box_noise",
    "epipolar_noise",
    "nis_ratio",
    "params_check",
    "params_warning",
]

log = logging.getLogger(__name__)

_MIN_INNOVATIONS = 20


def epipolar_noise(dataset: TeamDataset, kind: str) -> float | None:
    """Filter-free lower bound of the ``kind`` (``features``/``objects``) measurement σ.

    For every single stereo observation the residual orthogonal to the point Jacobian (the
    epipolar residual; ``(v_l − v_r)/√2`` for a rectified rig) has variance ``σ²`` when the four
    coordinates carry independent noise of std ``σ``. Returns its robust std over the team's
    observations (``None`` when there are fewer than 20), computed on the single-frame stereo
    point as linearisation point.
    """
    camera = dataset.calibration.camera
    z = np.concatenate([getattr(r, kind).measurements for r in dataset.robots])
    if z.shape[0] < _MIN_INNOVATIONS:
        return None
    p_cam, ok = stereo_point(camera, np.eye(4), np.eye(4), z)
    z, p_cam = z[ok], p_cam[ok]
    if z.shape[0] < _MIN_INNOVATIONS:
        return None
    jac = camera.project_jacobian(p_cam)  # (M, 4, 3)
    # the left null vector of each 4×3 Jacobian: the last left singular vector
    u, _, _ = np.linalg.svd(jac)
    normal = u[:, :, 3]
    residual = np.einsum("mi,mi->m", normal, z - camera.project(p_cam))
    return float(robust_std(residual))


def _box_detections(dataset: TeamDataset) -> bool:
    """Whether the team's objects are detections with a box size (each robot tracks them)."""
    return all(
        r.objects.ids.size == 0 and r.detections is not None and r.detections.sizes is not None
        for r in dataset.robots
    ) and any(r.detections.measurements.shape[0] for r in dataset.robots)


#: Size bins of the box-noise fits (fewer when there are fewer than 20 innovations a bin).
BOX_BINS = 8


def _fit_floor_share(
    size2: np.ndarray, variance: np.ndarray, count: np.ndarray, least2: float = 0.0
):
    """``(σ₀², α²)`` of ``variance ≈ σ₀² + α² · size2`` over bins, non-negative, each bin
    weighted by its count over its variance² (relative errors); ``σ₀² ≥ least2`` (the rest
    fitted to what the floor leaves)."""
    weight = np.sqrt(count) / np.maximum(variance, 1e-300)
    design = np.column_stack([np.ones_like(size2), size2]) * weight[:, None]
    solution, _ = optimize.nnls(design, (variance - least2) * weight)
    solution[0] += least2
    if solution[0] <= 0.0:  # a floor of zero: keep a thousandth of the smallest bin's σ²
        solution[0] = 1e-3 * float(variance.min())
    return float(solution[0]), float(solution[1])


#: Std of a box centre coordinate that the pixel grid alone gives, in pixels: each edge of a
#: box drawn on the image's pixels lies anywhere within its pixel (uniform, variance 1/12), the
#: centre is the mean of two edges (variance 1/24). An error that stays while the object's
#: image moves by less than a pixel a frame: the innovations cannot show it (the estimate
#: follows it), so :func:`calibrate` keeps the fitted floor ``σ₀`` at least this.
BOX_QUANTIZATION_STD = float(np.sqrt(1.0 / 24.0))


def box_quantization_std(dataset: TeamDataset) -> float:
    """The least box-centre σ of the team's boxes in the units of ``K``
    (:data:`BOX_QUANTIZATION_STD` where the images' size is known, their boxes then in
    pixels as :func:`~teamslam.msckf.filter.box_noise.box_rows` takes them; else 0)."""
    return BOX_QUANTIZATION_STD if dataset.calibration.image_size is not None else 0.0


def _bins(x: np.ndarray) -> list[np.ndarray]:
    """Indices of ``x`` in up to :data:`BOX_BINS` equal-count bins of at least 20."""
    n = min(BOX_BINS, x.size // _MIN_INNOVATIONS)
    order = np.argsort(x, kind="stable")
    return [part for part in np.array_split(order, max(n, 1)) if part.size]


def epipolar_box_noise(dataset: TeamDataset) -> tuple[float, float] | None:
    """Filter-free ``(σ₀, α)`` of box detections: :func:`epipolar_noise`'s residual, whose
    variance is ``σ₀² + α² Σ n_c² s_c²`` (``n`` its unit normal, ``s_c`` the box size along
    coordinate ``c``), fitted over bins of that size term by their robust variances.
    ``None`` with fewer than 20 stereo boxes."""
    camera = dataset.calibration.camera
    z = np.concatenate([r.detections.measurements for r in dataset.robots])
    sizes = np.concatenate([r.detections.sizes for r in dataset.robots])
    finite = np.all(np.isfinite(z), axis=1)
    z, sizes = z[finite], sizes[finite]
    if z.shape[0] < _MIN_INNOVATIONS:
        return None
    p_cam, ok = stereo_point(camera, np.eye(4), np.eye(4), z)
    z, sizes, p_cam = z[ok], sizes[ok], p_cam[ok]
    if z.shape[0] < _MIN_INNOVATIONS:
        return None
    u, _, _ = np.linalg.svd(camera.project_jacobian(p_cam))
    normal = u[:, :, 3]
    residual = np.einsum("mi,mi->m", normal, z - camera.project(p_cam))
    size2 = np.einsum("mi,mi->m", normal**2, np.concatenate([sizes, sizes], axis=1) ** 2)
    bins = _bins(size2)
    floor2, share2 = _fit_floor_share(
        np.array([size2[b].mean() for b in bins]),
        np.array([robust_std(residual[b]) ** 2 for b in bins]),
        np.array([b.size for b in bins], float),
    )
    return float(np.sqrt(floor2)), float(np.sqrt(share2))


def box_noise_fit(record: InnovationRecord, least_std: float = 0.0) -> tuple[float, float] | None:
    """``(σ₀, α)`` that the recorded box innovations show (covariance matching by box size).

    The innovations (whitened by the variance the filter used, :class:`InnovationRecord`) are
    binned by their mean squared box size; in each bin the factor ``ρ`` by which the noise
    exceeds the model is the maximum-likelihood one of the innovations' components, each
    ``c ~ N(0, λ + ρ)`` along its direction (``λ`` the state's share), ``c² / (λ + ρ)``
    winsorised at the χ²(1) quantile of :data:`NIS_WINSOR_PROBABILITY` — a direction the state
    dominates weighs next to nothing (matching the sum of the NIS instead takes a few per cent
    of miscalibration there as the noise itself); ``ρ`` times the bin's mean model variance is
    the variance the data show there; ``σ₀² + α² s²`` is fitted to those (non-negative least
    squares), ``σ₀`` at least ``least_std`` (:func:`box_quantization_std`). ``None`` with fewer
    than 20 innovations."""
    if len(record.c2) < _MIN_INNOVATIONS:
        return None
    c2, lam = np.array(record.c2), np.array(record.lam)
    size2 = np.array(record.size2).mean(axis=1)
    variance = np.array(record.variance).mean(axis=1)
    cap = stats.chi2.ppf(NIS_WINSOR_PROBABILITY, 1)
    shown, sizes, counts = [], [], []
    for b in _bins(size2):
        shown.append(_noise_factor(c2[b].ravel(), lam[b].ravel(), cap) * variance[b].mean())
        sizes.append(size2[b].mean())
        counts.append(b.size)
    floor2, share2 = _fit_floor_share(
        np.array(sizes), np.array(shown), np.array(counts, float), least_std**2
    )
    return float(np.sqrt(floor2)), float(np.sqrt(share2))


def _noise_factor(c2: np.ndarray, lam: np.ndarray, cap: float) -> float:
    """Maximum-likelihood ``ρ`` of components with ``c ~ N(0, λ + ρ)`` (``c2`` their squares),
    each ``c² / (λ + ρ)`` winsorised at ``cap``; searched over ``10⁻⁴ … 10⁴``."""

    def cost(log_rho: float) -> float:
        v = lam + np.exp(log_rho)
        return float(np.sum(np.log(v) + np.minimum(c2 / v, cap)))

    found = optimize.minimize_scalar(cost, bounds=(np.log(1e-4), np.log(1e4)), method="bounded")
    return float(np.exp(found.x))


#: NIS beyond this χ² quantile is winsorised (counted as the quantile) by :func:`nis_ratio`.
NIS_WINSOR_PROBABILITY = 1.0 - 1e-6


def nis_ratio(record: InnovationRecord, std: float) -> float | None:
    """Mean NIS of a sensor's innovations over its model value (1 when σ is right).

    ``Σ min(NIS_i, g_i) / Σ E[min(χ²(d_i), g_i)]``, each NIS winsorised at the χ² quantile
    ``g_i`` of probability ``1 − 10⁻⁶`` of its dof ``d_i`` and taken over the directions the state
    can explain (eigenvalues of ``H P Hᵀ`` above zero) — covariance matching (Mehra 1972;
    Bar-Shalom, Li & Kirubarajan 2001, §5.4). Why winsorised, and why only those directions: the
    concept page *Calibration*. ``None`` with fewer than 20 innovations.
    """
    dof, nis = [], []
    variance = std**2
    for c, lam in zip(record.c2, record.lam, strict=True):
        keep = lam > 1e-9 * max(float(lam.max()), variance)
        if keep.any():
            dof.append(int(keep.sum()))
            nis.append(float(np.sum(c[keep] / (lam[keep] + variance))))
    if len(dof) < _MIN_INNOVATIONS:
        return None
    d = np.array(dof)
    cap = stats.chi2.ppf(NIS_WINSOR_PROBABILITY, d)
    # E[min(X, g)] for X ~ χ²(d): d·F_{d+2}(g) + g·(1 − F_d(g))
    expected = np.sum(d * stats.chi2.cdf(cap, d + 2) + cap * (1.0 - NIS_WINSOR_PROBABILITY))
    return float(np.sum(np.minimum(nis, cap)) / expected)


class _Secant:
    """One noise level driven to ``ratio = 1`` in log space, by secant steps on ``log ratio``."""

    def __init__(self, value: float) -> None:
        self.log_value = float(np.log(value))
        self.previous: tuple[float, float] | None = None

    def step(self, ratio: float) -> float:
        """Move after a pass that gave ``ratio`` at the current value; returns |log step|."""
        log_ratio = float(np.log(ratio))
        slope = -2.0  # ratio ∝ σ⁻² when the measurement noise dominates the innovation
        if self.previous is not None:
            d_value = self.log_value - self.previous[0]
            if abs(d_value) > 0.05:  # closer passes differ by noise more than by slope
                slope = (log_ratio - self.previous[1]) / d_value
        # the state's share of the innovation (itself grown from σ) flattens the slope; never
        # let it flip, and never take more than twice the plain step σ·√ratio
        slope = float(np.clip(slope, -2.0, -0.5))
        step = float(np.clip(-log_ratio / slope, -np.log(10.0), np.log(10.0)))
        self.previous = (self.log_value, log_ratio)
        self.log_value += step
        return abs(step)

    @property
    def value(self) -> float:
        return float(np.exp(self.log_value))


@dataclass
class CalibrationResult:
    """A calibrated sensor model and how it was reached.

    Attributes
    ----------
    sensor_model
        The estimate (origin ``calibration``).
    iterations
        Per filter pass: the σ used, and the NIS / gate rejection it gave.
    converged
        Whether the last pass changed no σ by more than the tolerance.
    seconds
        Wall time of the whole calibration.
    frames
        Frames per robot used.
    start
        The filter-free starting values (epipolar bounds).
    """

    sensor_model: SensorModel
    iterations: list[dict] = field(default_factory=list)
    converged: bool = False
    seconds: float = 0.0
    frames: int = 0
    start: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """Plain JSON."""
        return {
            "sensor_model": self.sensor_model.to_json(),
            "iterations": self.iterations,
            "converged": self.converged,
            "seconds": self.seconds,
            "frames_per_robot": self.frames,
            "start": self.start,
        }


def default_frames(robots: int) -> int:
    """Frames per robot a calibration uses by default: about 1,200 robot-frames per pass,
    between 100 and 400 per robot."""
    return int(np.clip(1200 // max(robots, 1), 100, 400))


def _odometry_variances(health: SensorHealth, current: np.ndarray, per_axis: bool) -> np.ndarray:
    """Per-axis odometry variances from the lag normal equations (non-negative least squares).

    Unless ``per_axis``, one variance for the three translation axes and one for the three
    rotation axes (the fit's columns summed per group); an axis the data cannot see keeps a
    thousandth of its current value at least.
    """
    groups = np.eye(6) if per_axis else np.kron(np.eye(2), np.ones((3, 1)))  # (6, k)
    normal = groups.T @ health.lag_normal @ groups
    rhs = groups.T @ health.lag_rhs
    factor = np.linalg.cholesky(normal + 1e-12 * np.trace(normal) * np.eye(normal.shape[0]))
    solution, _ = optimize.nnls(factor.T, np.linalg.solve(factor, rhs))
    return np.maximum(groups @ solution, 1e-3 * current)


def _pass(dataset: TeamDataset, config: MsckfConfig, frames: int) -> SensorHealth:
    """Every robot's filter alone over its first ``frames`` frames, innovations recorded.

    The noise measured is the one of a box per frame: the factor learned on top of it from
    evidence beyond the window (``filter.object_overconfidence``) stays 1 here."""
    config = config.with_(filter={"object_overconfidence": False})
    parts = []
    for i, robot in enumerate(dataset.robots):
        agent = MsckfAgent(
            i, dataset.calibration, robot.head(frames), config, record_innovations=True
        )
        for t in range(agent.n_frames):
            agent.step(t)
        agent.flush_odometry_health()
        parts.append(agent.health)
    return SensorHealth.combine(parts)


def calibrate(
    dataset: TeamDataset,
    config: MsckfConfig,
    frames: int | None = None,
    max_iterations: int = 12,
    tolerance: float = 0.05,
    odometry_per_axis: bool = False,
) -> CalibrationResult:
    """Estimate the team's sensor model from its data (concept page *Calibration*).

    Parameters
    ----------
    dataset
        The team; its ground truth, if any, is not used (only each robot's first pose, which
        the filter also uses as its known start).
    config
        Every other setting (window, gates, which sensors to use) and the starting σ.
    frames
        Frames per robot to calibrate on (``None``: :func:`default_frames`).
    max_iterations
        Most filter passes.
    tolerance
        Stop when no σ changes by more than this fraction.
    odometry_per_axis
        Fit six odometry σ instead of one for translation and one for rotation. Only for data
        that see the motion along every axis well: an axis the measurements barely observe
        (e.g. forward motion seen through distant objects) converges slowly and stays poorly
        determined.
    """
    begin = time.perf_counter()
    boxes = config.filter.use_objects and _box_detections(dataset)
    use = {
        "features": config.filter.use_geometric_features
        and any(r.features.ids.size for r in dataset.robots),
        "objects": config.filter.use_objects
        and (any(r.objects.ids.size for r in dataset.robots) or boxes),
    }
    if frames is None:
        frames = default_frames(dataset.n_robots)
    if frames < 2:
        raise InputError("calibration needs at least 2 frames per robot")
    frames = min(max(r.frames for r in dataset.robots), frames)
    start: dict = {}
    std = {"features": config.filter.feature_std, "objects": config.filter.object_std}
    for sensor in SENSORS:
        if sensor == "objects" and boxes:
            continue
        bound = epipolar_noise(dataset, sensor) if use[sensor] else None
        start[f"{sensor}_epipolar_std"] = bound
        if bound is not None:
            std[sensor] = max(std[sensor], 3.0 * bound)
    share = config.filter.object_size_share
    if boxes:
        # from above, like the others: three times the filter-free floor and share
        bound = epipolar_box_noise(dataset)
        start["objects_epipolar_std"], start["objects_epipolar_size_share"] = bound or (None, None)
        if bound is not None:
            std["objects"], share = 3.0 * bound[0], 3.0 * bound[1]
    # start the odometry from above: a filter that trusts its odometry too much explains the
    # data by odometry and EM then crawls; one that trusts it too little lets the data speak
    log_odometry = np.log(3.0 * np.asarray(config.filter.odometry_std))
    searches = {sensor: _Secant(value) for sensor, value in std.items()}
    iterations: list[dict] = []
    converged = False
    for _ in range(max_iterations):
        current = config.with_(
            filter={
                "feature_std": searches["features"].value,
                "object_std": searches["objects"].value,
                "object_size_share": share,
                "odometry_std": tuple(np.exp(log_odometry)),
            }
        )
        health = _pass(dataset, current, frames)
        summary = health.summary()
        entry = {
            "odometry_std": list(current.filter.odometry_std),
            "feature_std": current.filter.feature_std if use["features"] else None,
            "object_std": current.filter.object_std if use["objects"] else None,
            "object_size_share": share if boxes else None,
            "nis": summary["nis"],
            "gate_rejection_rate": summary["gate_rejection_rate"],
        }
        iterations.append(entry)
        change = 0.0
        for sensor in SENSORS:
            if not use[sensor]:
                continue
            if sensor == "objects" and boxes:
                found = box_noise_fit(health.records[sensor], box_quantization_std(dataset))
                if found is not None:
                    old = np.log([searches[sensor].value, max(share, 1e-12)])
                    searches[sensor] = _Secant(found[0])
                    share = found[1]
                    new = np.log([found[0], max(share, 1e-12)])
                    # a share the data put at zero stays there: no change to count
                    moved = np.abs(new - old)[: 2 if share > 1e-9 else 1]
                    change = max(change, float(np.max(moved)))
                continue
            ratio = nis_ratio(health.records[sensor], searches[sensor].value)
            entry[f"{sensor}_nis_ratio"] = ratio
            if ratio is not None:
                change = max(change, searches[sensor].step(ratio))
        if health.lag_rows >= _MIN_INNOVATIONS:
            variances = _odometry_variances(health, np.exp(2 * log_odometry), odometry_per_axis)
            target = 0.5 * np.log(variances)
            step = target - log_odometry
            log_odometry = target
            change = max(change, float(np.max(np.abs(step))))
        log.info("calibration pass %d: %s", len(iterations), entry)
        if change < np.log1p(tolerance):
            converged = True
            break
    noise = SensorNoise(
        odometry_std=tuple(float(v) for v in np.exp(log_odometry)),
        feature_std=searches["features"].value if use["features"] else None,
        object_std=searches["objects"].value if use["objects"] else None,
        object_size_share=share if boxes else None,
    )
    seconds = time.perf_counter() - begin
    note = (
        f"teamslam calibrate: {len(iterations)} passes over {frames} frames per robot"
        f"{'' if converged else ' (not converged)'}"
    )
    return CalibrationResult(
        SensorModel(noise, origin="calibration", note=note),
        iterations,
        converged,
        seconds,
        frames,
        start,
    )


def calibration_json(dataset: TeamDataset, result: CalibrationResult) -> dict:
    """What ``teamslam calibrate --json`` prints: the result and the dataset's sensor model."""
    payload = result.to_json()
    if dataset.sensor_model is not None:
        payload["dataset_sensor_model"] = dataset.sensor_model.to_json()
    return payload


def calibration_table(dataset: TeamDataset, result: CalibrationResult) -> str:
    """The calibrated noise levels beside the dataset's, and the last pass's NIS."""
    from teamslam.textio import format_value

    noise = result.sensor_model.team
    old = dataset.sensor_model.team if dataset.sensor_model is not None else None
    lines = [
        f"{dataset.name}: calibrated from {result.frames} frames per robot in "
        f"{result.seconds:.1f} s, {len(result.iterations)} filter passes"
        f"{'' if result.converged else ' (not converged)'}",
        f"{'':<22}{'calibrated':>44}"
        + (f"  {'dataset (' + dataset.sensor_model.origin + ')':>44}" if old else ""),
    ]

    for label, key in (
        ("odometry σ (m, rad)", "odometry_std"),
        ("feature σ (K units)", "feature_std"),
        ("object σ (K units)", "object_std"),
        ("object σ share of box", "object_size_share"),
        ("object depth (m)", "object_depth_range"),  # not calibrated: shown for reference
    ):
        if key == "object_size_share" and noise.object_size_share is None:
            continue  # only for detections with box sizes
        row = f"{label:<22}{format_value(getattr(noise, key)):>44}"
        if old is not None:
            row += f"  {format_value(getattr(old, key)):>44}"
        lines.append(row)
    start = result.start
    for sensor in ("features", "objects"):
        bound = start.get(f"{sensor}_epipolar_std")
        if bound is not None:
            lines.append(
                f"{sensor} left/right-independent noise (epipolar residual): {bound:.4g} K units"
            )
    last = result.iterations[-1]
    health = ", ".join(f"{s} NIS/dof {v:.2f}" for s, v in last["nis"].items() if v is not None)
    if health:
        lines.append(f"last pass: {health}")
    return "\n".join(lines)


def params_check(dataset: TeamDataset) -> list[tuple[str, float, float]]:
    """A params file's noise levels (the dataset's sensor model) beside a calibration from
    the data: ``(label, given, found)`` per level both give."""
    from teamslam.msckf.configure import build_settings
    from teamslam.msckf.settings.sources import calibration_start

    start = calibration_start(dataset, build_settings(dataset, calibrate="never").config)
    found_noise = calibrate(dataset, start).sensor_model.team
    given_noise = dataset.sensor_model.team

    def pick(noise) -> dict:
        odometry = noise.odometry_std
        return {
            "odometry σ translation (m)": None if odometry is None else max(odometry[:3]),
            "odometry σ rotation (rad)": None if odometry is None else max(odometry[3:]),
            "feature σ": noise.feature_std,
            "object σ": noise.object_std,
        }

    given, found = pick(given_noise), pick(found_noise)
    return [
        (label, given[label], found[label])
        for label in given
        if given[label] is not None and found[label] is not None
    ]


def params_warning(label: str, given: float, found: float, path) -> str | None:
    """The warning when a params file's level is off by more than 3× from the data's."""
    if 1 / 3 <= given / found <= 3:
        return None
    return (
        f"the params file's {label} ({given:.4g}) is {given / found:.2g}× what the data show "
        f"({found:.4g}); `teamslam calibrate {path} --write` replaces it"
    )
