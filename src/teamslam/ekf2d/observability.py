"""Local observability matrix of a linearised filter (FEJ multi-robot EKF paper, §3, eq. 13).

Over steps ``k … k + m``

    M = [ H_k ; H_{k+1} Φ_k ; … ; H_{k+m} Φ_{k+m-1} ⋯ Φ_k ]                              (13)

built from the Jacobians a run actually used (:class:`~teamslam.ekf2d.filter.JacobianRecord`).
For two robots and two features (state dimension 10) the underlying system has 3 unobservable
directions (global translation and rotation): the ideal and first-estimate filters keep
``rank M = 7``, the standard filter reaches ``rank M = 8`` (Lemma 1) — it believes it can see
a direction it cannot.
"""

from __future__ import annotations

import numpy as np

from teamslam.ekf2d.filter import JacobianRecord
from teamslam.errors import InputError
from teamslam.linalg import nullspace, rank

__all__ = ["nullspace", "observability_matrix", "rank"]


def observability_matrix(record: JacobianRecord, start: int, length: int) -> np.ndarray:
    """Stack (13) over steps ``start … start + length`` of a recorded run.

    ``record.h[k]`` is the update Jacobian of step ``k`` and ``record.phi[k]`` the propagation
    ``k → k + 1``. The state dimension must not change inside the window.
    """
    if start < 0 or length < 0 or start + length >= len(record.h):
        raise InputError(
            f"window {start}..{start + length} outside the {len(record.h)} recorded steps"
        )
    dim = record.h[start].shape[1]
    blocks = [record.h[start]]
    transition = np.eye(dim)
    for t in range(1, length + 1):
        k = start + t
        phi = record.phi[k - 1]
        if phi.shape != (dim, dim) or record.h[k].shape[1] != dim:
            raise InputError(
                f"state dimension changes at step {k}; pick a window without new features"
            )
        transition = phi @ transition
        blocks.append(record.h[k] @ transition)
    return np.vstack(blocks)
