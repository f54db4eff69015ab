"""Local observability matrix of a linearised filter (FEJ multi-robot EKF paper, §3, eq. 13).

``M = [H_k; H_{k+1} Φ_k; …]`` from the Jacobians a run used
(:class:`~teamslam.ekf2d.filter.JacobianRecord`), and its rank: ``dim − 3`` for the ideal and
first-estimate filters, ``dim − 2`` for the standard one (Lemma 1). See the concept page
*Linearisation* (``docs/concepts/linearization.md``).
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
