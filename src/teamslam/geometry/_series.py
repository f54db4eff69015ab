"""Numerically safe scalar coefficients of the SO(3)/SE(3)/SE(2) closed forms.

Every closed form of the exponential map and its Jacobians is a polynomial in the
Lie-algebra element with coefficients that are ratios of trigonometric functions of the
angle θ, such as ``sin θ / θ``. Each ratio is finite at θ = 0 but its direct evaluation
cancels catastrophically there. Below a threshold the functions here switch to the Taylor
series in ``x = θ²``; the series keep five terms, so at the threshold θ = 0.1 their
truncation error is below 1e-17 while the direct formula loses at most ~1e-11 relative at
the same point (the worst case, ``c3`` with its θ⁵ denominator).
"""

from __future__ import annotations

import numpy as np

SERIES_THRESHOLD = 0.1


def _blend(theta: np.ndarray, series, direct) -> np.ndarray:
    """Evaluate ``series(θ²)`` where θ is small and ``direct(θ)`` elsewhere, without warnings."""
    theta = np.asarray(theta, dtype=float)
    small = theta < SERIES_THRESHOLD
    if not np.any(small):
        return direct(theta)
    far = direct(np.where(small, 1.0, theta))  # the placeholder 1.0 keeps it finite
    return np.where(small, series(theta * theta), far)


def _poly(x: np.ndarray, coefficients: tuple[float, ...]) -> np.ndarray:
    out = np.zeros_like(x)
    for c in reversed(coefficients):
        out = out * x + c
    return out


def sinc(theta: np.ndarray) -> np.ndarray:
    """``sin θ / θ``."""
    return _blend(
        theta,
        lambda x: _poly(x, (1.0, -1 / 6, 1 / 120, -1 / 5040, 1 / 362880)),
        lambda t: np.sin(t) / t,
    )


def one_minus_cos_over_sq(theta: np.ndarray) -> np.ndarray:
    """``(1 - cos θ) / θ²``."""
    return _blend(
        theta,
        lambda x: _poly(x, (1 / 2, -1 / 24, 1 / 720, -1 / 40320, 1 / 3628800)),
        lambda t: (1.0 - np.cos(t)) / (t * t),
    )


def theta_minus_sin_over_cube(theta: np.ndarray) -> np.ndarray:
    """``(θ - sin θ) / θ³``."""
    return _blend(
        theta,
        lambda x: _poly(x, (1 / 6, -1 / 120, 1 / 5040, -1 / 362880, 1 / 39916800)),
        lambda t: (t - np.sin(t)) / t**3,
    )


def inverse_jacobian_coefficient(theta: np.ndarray) -> np.ndarray:
    """``(1 - θ sin θ / (2 (1 - cos θ))) / θ²``, the φ^² coefficient of J_l⁻¹ on SO(3).

    Written with ``sin θ / (1 - cos θ)`` (= cot(θ/2)) so that it stays accurate up to θ = π.
    """
    return _blend(
        theta,
        lambda x: _poly(x, (1 / 12, 1 / 720, 1 / 30240, 1 / 1209600, 1 / 47900160)),
        lambda t: (1.0 - t * np.sin(t) / (2.0 * (1.0 - np.cos(t)))) / (t * t),
    )


def se3_q_c2(theta: np.ndarray) -> np.ndarray:
    """``(θ² + 2 cos θ - 2) / (2 θ⁴)``, second coefficient of the SE(3) Q matrix."""
    return _blend(
        theta,
        lambda x: _poly(x, (1 / 24, -1 / 720, 1 / 40320, -1 / 3628800, 1 / 479001600)),
        lambda t: (t * t + 2.0 * np.cos(t) - 2.0) / (2.0 * t**4),
    )


def se3_q_c3(theta: np.ndarray) -> np.ndarray:
    """``(2θ - 3 sin θ + θ cos θ) / (2 θ⁵)``, third coefficient of the SE(3) Q matrix."""
    return _blend(
        theta,
        lambda x: _poly(x, (1 / 120, -1 / 2520, 1 / 120960, -1 / 9979200, 1 / 1245404160)),
        lambda t: (2.0 * t - 3.0 * np.sin(t) + t * np.cos(t)) / (2.0 * t**5),
    )
