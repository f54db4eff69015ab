"""Lie groups SO(3), SE(3), SE(2): exp/log, adjoints, left/right Jacobians, batched.

Perturbation convention of every filter in teamslam (distributed-MSCKF paper, eq. 20): an
uncertain pose is its estimate composed on the **right** with a body-frame twist,
``T_true = T_hat · exp(ε^)``, ``ε = (ε_ρ, ε_φ)``, translation first; corrections are
``T ← T · exp(δ^)`` and ``T exp(ε^) = exp((Ad(T) ε)^) T``. SE(2) follows the same rule
(``(ρx, ρy, θ)``). Every function takes arbitrary leading (batch) axes and is numerically safe
near zero angle and near π.
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
