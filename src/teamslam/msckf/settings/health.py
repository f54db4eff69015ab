"""Health of every sensor of a running filter: innovation statistics and odometry residuals.

Each measurement the filter tests — a geometric feature's null-space residual, the stereo
residual of an object in the map — has an innovation ``r``
with covariance ``S = H P Hᵀ + σ² I``. Its normalised innovation squared ``NIS = rᵀ S⁻¹ r``
is χ²-distributed with ``dim r`` degrees of freedom when the model is right, so per sensor

* ``nis`` — ΣNIS / Σdof over every tested innovation, before gating — is ≈ 1 when σ is right,
  ≪ 1 when σ is too large (the sensor is being ignored), ≫ 1 when it is too small;
* ``gate_rejection_rate`` is ≈ 1 − gate probability when σ is right.

The odometry has no innovation in the MSCKF (it drives propagation), so its health is measured
on the window: when the oldest pose leaves it, the pair (oldest, next) has been smoothed by
every measurement of the window, and the residual ``ê = log(δT̂⁻¹ u)`` of the odometry ``u``
against the smoothed relative pose ``δT̂``, with its smoothed covariance ``Σₑ``, gives the
expectation–maximisation statistic ``E[n nᵀ | data] = ê êᵀ + Σₑ`` (Shumway & Stoffer 1982;
Särkkä, *Bayesian Filtering and Smoothing*, 2013, §12.3.3) of the odometry noise ``n``. Its
ratio to the assumed ``W`` is ≈ 1 when W is right (closer to 1 than the truth warrants when
the measurements say little about the motion).

With ``record=True`` the odometry statistic is also taken over every lag ``L`` of the window
(pose 0 against pose ``L``, see :func:`odometry_lag_residuals`), accumulated as the normal
equations of a least-squares fit of the per-axis noise variances, and every innovation is kept
in the eigenbasis of ``S`` — squared components ``c² = (Vᵀ r)²`` and ``λ(H P Hᵀ) = λ(S) − σ²``
— so that :mod:`teamslam.msckf.calibration` can recompute its NIS for any other σ.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from teamslam.geometry import se3

__all__ = [
    "HEALTHY_NIS",
    "HEALTHY_REJECTION",
    "SENSORS",
    "InnovationRecord",
    "SensorHealth",
    "health_warnings",
    "odometry_lag_residuals",
    "odometry_step_residual",
]

SENSORS = ("features", "objects")


@dataclass
class InnovationRecord:
    """Innovations of one sensor in the eigenbasis of their covariance (for calibration).

    Attributes
    ----------
    c2
        Per innovation, the squared components ``(Vᵀ r)²``.
    lam
        Per innovation, the eigenvalues of ``H P Hᵀ`` (the state's share of ``S``).
    size2, variance
        Innovations whose coordinates each had their own noise (box rows): per innovation the
        squared box size along each coordinate's axis and the variance the filter used, ``c2``
        and ``lam`` then being those of the innovation whitened by that variance (unit
        noise). Clipped boxes are not recorded. Empty otherwise.
    """

    c2: list[np.ndarray] = field(default_factory=list)
    lam: list[np.ndarray] = field(default_factory=list)
    size2: list[np.ndarray] = field(default_factory=list)
    variance: list[np.ndarray] = field(default_factory=list)


def odometry_lag_residuals(
    poses: np.ndarray, odometry: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of the composed odometry from window pose 0 to every later window pose.

    Parameters
    ----------
    poses
        ``(c, 4, 4)`` smoothed window poses of consecutive frames.
    odometry
        ``(c − 1, 4, 4)`` the odometry between them.
    cov
        ``(6c, 6c)`` their joint covariance.

    Returns
    -------
    second_moment, design
        ``(c − 1, 6)`` diagonals of ``E[ν νᵀ | data] = ê êᵀ + J Σ Jᵀ`` for lags ``L = 1…c−1``,
        and ``(c − 1, 6, 6)`` matrices ``M_L`` with ``diag Cov ν_L = M_L diag W``: the composed
        odometry is ``U_L = Δ_L exp(ν_L)``, ``ν_L ≈ Σ_j Ad(B_j⁻¹) n_j`` where ``B_j`` composes the
        steps after ``j``, so ``M_L = Σ_j Ad(B_j⁻¹) ∘ Ad(B_j⁻¹)`` (element-wise squares).

    With ``T_i = T̂_i exp(ε_i)`` the relative pose is ``Δ̂_L exp(ε_L − Ad(Δ̂_L⁻¹) ε₀)`` to first
    order, so ``ν_L ≈ ê_L − (ε_L − Ad(Δ̂_L⁻¹) ε₀)`` with ``ê_L = log(Δ̂_L⁻¹ U_L)`` and
    ``Cov(ν_L | data) = J Σ Jᵀ``, ``J = [Ad(Δ̂_L⁻¹), −I]`` on poses 0 and ``L``. Lag 1 of two
    poses is the one-step statistic of the odometry's health.
    """
    c = poses.shape[0]
    prefix = np.empty((c, 4, 4))  # P_m = u_0 ⋯ u_{m−1}
    prefix[0] = np.eye(4)
    for m in range(1, c):
        prefix[m] = prefix[m - 1] @ odometry[m - 1]
    relative = se3.inverse(poses[0]) @ poses[1:]  # Δ̂_L
    residual = se3.log(se3.inverse(relative) @ prefix[1:])
    ad_prefix = se3.adjoint(prefix)
    ad_prefix_inv = se3.adjoint(se3.inverse(prefix))
    # Ad(B_j⁻¹) for lag L = Ad(P_L⁻¹ P_{j+1}) = Ad(P_L)⁻¹ Ad(P_{j+1}), j = 0 … L − 1
    pairs = np.einsum("lab,jbc->ljac", ad_prefix_inv[1:], ad_prefix[1:]) ** 2
    below = np.tril(np.ones((c - 1, c - 1), dtype=bool))  # j + 1 ≤ L
    design = np.einsum("lj,ljac->lac", below, pairs)
    jac_first = se3.adjoint(se3.inverse(relative))  # (c − 1, 6, 6)
    p00 = cov[:6, :6]
    p0l = cov[:6, 6:].reshape(6, c - 1, 6).transpose(1, 0, 2)  # (L, 6, 6) Σ_{0L}
    pll = np.einsum("lalb->lab", cov[6:, 6:].reshape(c - 1, 6, c - 1, 6))
    # J = [Ad(Δ̂⁻¹), −I]: diag(A Σ00 Aᵀ − A Σ0L − Σ_L0 Aᵀ + Σ_LL)
    a_p00 = np.einsum("lab,bc,lac->la", jac_first, p00, jac_first)
    cross = np.einsum("lab,lba->la", jac_first, p0l)
    var = a_p00 - 2.0 * cross + np.einsum("laa->la", pll)
    return residual**2 + var, design


def odometry_step_residual(poses: np.ndarray, odometry: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Lag 1 of :func:`odometry_lag_residuals` alone: ``ê² + diag(J Σ Jᵀ)`` for one step.

    Parameters
    ----------
    poses
        ``(2, 4, 4)`` two smoothed window poses of consecutive frames.
    odometry
        ``(4, 4)`` the odometry between them.
    cov
        ``(12, 12)`` their joint covariance.

    Returns
    -------
    numpy.ndarray
        ``(6,)`` the diagonal of ``E[ν νᵀ | data]``, the same numbers as row 0 of the second
        moment of :func:`odometry_lag_residuals` without the design matrices the lags need.
    """
    relative = se3.inverse(poses[0]) @ poses[1]  # Δ̂
    to_first = se3.inverse(relative)
    residual = se3.log(to_first @ odometry)
    jac_first = se3.adjoint(to_first)  # J = [Ad(Δ̂⁻¹), −I]
    var = (
        np.einsum("ab,bc,ac->a", jac_first, cov[:6, :6], jac_first)
        - 2.0 * np.einsum("ab,ba->a", jac_first, cov[:6, 6:])
        + np.diagonal(cov[6:, 6:])
    )
    return residual**2 + var


class SensorHealth:
    """Running innovation statistics of each sensor, and odometry residual statistics.

    Parameters
    ----------
    record
        Also keep every innovation for calibration (costs an eigendecomposition each).
    """

    def __init__(self, record: bool = False) -> None:
        self.record = record
        self.nis_sum = dict.fromkeys(SENSORS, 0.0)
        self.dof_sum = dict.fromkeys(SENSORS, 0)
        self.tested = dict.fromkeys(SENSORS, 0)
        self.rejected = dict.fromkeys(SENSORS, 0)
        self.records = {s: InnovationRecord() for s in SENSORS}
        self.odometry_ratio_sum = np.zeros(6)  # Σ (ê² + diag Σₑ) / diag W
        self.odometry_steps = 0
        self.lag_normal = np.zeros((6, 6))  # Σ w M_rowᵀ M_row over lags (record mode)
        self.lag_rhs = np.zeros(6)
        self.lag_rows = 0

    def test(
        self,
        sensor: str,
        residual: np.ndarray,
        innovation_cov: np.ndarray,
        variance: float | np.ndarray,
        threshold: np.ndarray | float,
        size2: np.ndarray | None = None,
        clipped: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """χ² test of ``G`` innovations ``(G, d)`` with covariances ``(G, d, d)``; returns the
        acceptance mask and each innovation's NIS, and accumulates the NIS.

        ``variance`` is the measurement noise variance in ``S``: one for all, or ``(G, d)`` per
        coordinate (box rows, with ``size2`` and ``clipped`` per innovation for the record)."""
        residual = np.asarray(residual, dtype=float)
        g = residual.shape[0]
        if g == 0:
            return np.zeros(0, dtype=bool), np.zeros(0)
        nis = np.einsum(
            "gi,gi->g", residual, np.linalg.solve(innovation_cov, residual[..., None])[..., 0]
        )
        accepted = nis < threshold
        self.nis_sum[sensor] += float(nis.sum())
        self.dof_sum[sensor] += g * residual.shape[1]
        self.tested[sensor] += g
        self.rejected[sensor] += int(g - accepted.sum())
        if self.record and np.ndim(variance) == 2:
            keep = ~clipped
            scale = 1.0 / np.sqrt(variance[keep])
            white = innovation_cov[keep] * scale[:, :, None] * scale[:, None, :]
            lam, vec = np.linalg.eigh(white)
            c2 = np.einsum("gji,gj->gi", vec, residual[keep] * scale) ** 2
            rec = self.records[sensor]
            rec.c2.extend(c2)
            rec.lam.extend(np.maximum(lam - 1.0, 0.0))
            rec.size2.extend(size2[keep])
            rec.variance.extend(variance[keep])
        elif self.record:
            lam, vec = np.linalg.eigh(innovation_cov)
            c2 = np.einsum("gji,gj->gi", vec, residual) ** 2
            rec = self.records[sensor]
            rec.c2.extend(c2)
            rec.lam.extend(np.maximum(lam - variance, 0.0))
        return accepted, nis

    def odometry(self, second_moment: np.ndarray, assumed_var: np.ndarray) -> None:
        """Add one step's smoothed ``ê² + diag Σₑ`` (lag 1 of :func:`odometry_lag_residuals`)."""
        self.odometry_ratio_sum += second_moment / assumed_var
        self.odometry_steps += 1

    def odometry_lags(self, second_moment: np.ndarray, design: np.ndarray, assumed_var):
        """Add the lag residuals of :func:`odometry_lag_residuals` to the normal equations of
        ``second_moment ≈ design · diag W``, each row weighted by its predicted value⁻²."""
        predicted = design @ np.asarray(assumed_var)
        weight = 1.0 / np.maximum(predicted, 1e-300) ** 2
        self.lag_normal += np.einsum("la,lab,lac->bc", weight, design, design)
        self.lag_rhs += np.einsum("la,lab,la->b", weight, design, second_moment)
        self.lag_rows += second_moment.size

    def to_json(self) -> dict:
        """The running sums (not the recorded innovations), to combine across processes."""
        return {
            "nis_sum": self.nis_sum,
            "dof_sum": self.dof_sum,
            "tested": self.tested,
            "rejected": self.rejected,
            "odometry_ratio_sum": self.odometry_ratio_sum.tolist(),
            "odometry_steps": self.odometry_steps,
        }

    @classmethod
    def from_json(cls, data: dict) -> SensorHealth:
        """Inverse of :meth:`to_json`."""
        health = cls()
        for name in ("nis_sum", "dof_sum", "tested", "rejected"):
            getattr(health, name).update({s: data[name][s] for s in SENSORS})
        health.odometry_ratio_sum = np.asarray(data["odometry_ratio_sum"], dtype=float)
        health.odometry_steps = int(data["odometry_steps"])
        return health

    @staticmethod
    def combine(parts: list[SensorHealth]) -> SensorHealth:
        """One set of statistics over several robots (records included)."""
        total = SensorHealth(record=any(p.record for p in parts))
        for p in parts:
            for s in SENSORS:
                total.nis_sum[s] += p.nis_sum[s]
                total.dof_sum[s] += p.dof_sum[s]
                total.tested[s] += p.tested[s]
                total.rejected[s] += p.rejected[s]
                total.records[s].c2.extend(p.records[s].c2)
                total.records[s].lam.extend(p.records[s].lam)
                total.records[s].size2.extend(p.records[s].size2)
                total.records[s].variance.extend(p.records[s].variance)
            total.odometry_ratio_sum += p.odometry_ratio_sum
            total.odometry_steps += p.odometry_steps
            total.lag_normal += p.lag_normal
            total.lag_rhs += p.lag_rhs
            total.lag_rows += p.lag_rows
        return total

    def summary(self) -> dict:
        """``nis`` and ``gate_rejection_rate`` per sensor (``None`` where nothing was tested),
        counts, and the odometry's second-moment ratio (translation, rotation)."""
        nis, rejection, tested = {}, {}, {}
        for s in SENSORS:
            tested[s] = self.tested[s]
            nis[s] = self.nis_sum[s] / self.dof_sum[s] if self.dof_sum[s] else None
            rejection[s] = self.rejected[s] / self.tested[s] if self.tested[s] else None
        ratio = None
        if self.odometry_steps:
            r = self.odometry_ratio_sum / self.odometry_steps
            ratio = {"translation": float(r[:3].mean()), "rotation": float(r[3:].mean())}
        return {
            "nis": nis,
            "gate_rejection_rate": rejection,
            "innovations_tested": tested,
            "odometry_residual_ratio": ratio,
        }


#: NIS / dof (and odometry second-moment ratio) outside this band draws a warning.
HEALTHY_NIS = (0.2, 5.0)
#: A gate rejecting more than this share of a sensor's measurements draws a warning.
HEALTHY_REJECTION = 0.3
_NAMES = {"features": "geometric-feature", "objects": "object"}
_SETTING = {"features": "filter.feature_std", "objects": "filter.object_std"}


def health_warnings(summary: dict) -> list[str]:
    """One line per sensor whose statistics say its σ is wrong, naming the likely cause.

    ``summary`` is :meth:`SensorHealth.summary` (of a robot or of the team).
    """
    low, high = HEALTHY_NIS
    lines = []
    for sensor in SENSORS:
        nis = summary["nis"].get(sensor)
        rejected = summary["gate_rejection_rate"].get(sensor)
        name, setting = _NAMES[sensor], _SETTING[sensor]
        if nis is not None and nis < low:
            lines.append(
                f"{name} measurements: NIS/dof {nis:.3g} < {low}: the filter is all but ignoring "
                f"them; {name} σ ({setting}) probably too large"
            )
        elif nis is not None and nis > high:
            lines.append(
                f"{name} measurements: NIS/dof {nis:.3g} > {high}: {name} σ ({setting}) "
                "probably too small, or the data hold outliers"
            )
        if rejected is not None and rejected > HEALTHY_REJECTION:
            lines.append(
                f"{name} measurements: the χ² gate rejects {100 * rejected:.0f}% of them; "
                f"{name} σ ({setting}) probably too small"
            )
    ratio = summary.get("odometry_residual_ratio")
    for part in ("translation", "rotation"):
        value = None if ratio is None else ratio[part]
        if value is not None and value < low:
            lines.append(
                f"odometry {part}: smoothed residuals are {value:.3g}× the assumed variance; "
                "odometry σ (filter.odometry_std) probably too large"
            )
        elif value is not None and value > high:
            lines.append(
                f"odometry {part}: smoothed residuals are {value:.3g}× the assumed variance; "
                "odometry σ (filter.odometry_std) probably too small"
            )
    return lines
