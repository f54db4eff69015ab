"""Lie groups SO(3), SE(3), SE(2): exp/log, adjoints, left/right Jacobians, batched.

Perturbation convention (distributed-MSCKF paper, eq. 20), used by every filter in teamslam
----------------------------------------------------------------------------------------------
An uncertain pose is its estimate composed on the **right** with a small random twist
expressed in the pose's own (body) frame::

    T_true = T_hat · exp(ε^),    ε = (ε_ρ, ε_φ) ~ N(0, Σ),    translation first, rotation second.

So a pose covariance is a covariance of a body-frame twist, an estimate is corrected by
``T ← T · exp(δ^)`` (eqs. 21, 28), and a Jacobian "with respect to a pose" is the derivative
with respect to ε at ε = 0. Moving a right perturbation to the left uses the adjoint:
``T exp(ε^) = exp((Ad(T) ε)^) T``. Planar poses follow the same rule on SE(2)
(``(ρx, ρy, θ)`` ordering).

Each module works on arrays with arbitrary leading (batch) axes and is numerically safe near
zero angle (Taylor series) and near π (the rotation log takes the axis from the symmetric part).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = ["alignment", "se2", "se3", "so3"]

__getattr__, __dir__ = attach(
    __name__,
    ("alignment", "camera", "se2", "se3", "so3"),
    {},
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.geometry import alignment, se2, se3, so3
