"""Distributed mirror descent for linear-Gaussian models in lifted form (Prop. 3, eqs. 11–17).

Local posteriors (eq. 17) of each agent's lifted model, and the iterations of the distributed
mirror descent (eq. 16) in information form (:func:`mirror_descent_step`, App. B eq. 42) and as
average + Prop. 2 + step (:func:`mirror_descent_step_moment`); the two agree. With steps
``α_k → 0``, ``Σ α_k = ∞`` on a connected graph the agents reach the centralised posterior
mean, provided the common prior is shared out (:func:`split_common_prior`). Derivation: the
concept page *Consensus* (``docs/concepts/consensus.md``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import scipy.linalg

from teamslam.dvi.models import LinearGaussianModel
from teamslam.errors import InputError
from teamslam.gaussian import (
    Gaussian,
    InformationGaussian,
    add_weighted_difference,
    geometric_average,
    spd_inverse,
)

__all__ = [
    "LiftedModel",
    "centralized_lifted_posterior",
    "lifted_common_index",
    "local_posterior",
    "mirror_descent",
    "mirror_descent_step",
    "mirror_descent_step_moment",
    "split_common_prior",
]


class LiftedModel:
    """The lifted matrices of eq. (12) for one agent over ``T + 1`` time steps.

    Attributes
    ----------
    f_bar_inv
        ``F̄⁻¹``: identity blocks on the diagonal, ``-F`` below it (so ``F̄⁻¹ s - Ḡ u`` is the
        stacked process-noise residual; ``F̄`` itself is never formed).
    g_bar, w_bar, h_bar, v_bar
        ``Ḡ``, ``W̄ = blkdiag(Σ₀, I_T ⊗ W)``, ``H̄ = I_{T+1} ⊗ H``, ``V̄ = I_{T+1} ⊗ V``.
    """

    def __init__(self, model: LinearGaussianModel, steps: int) -> None:
        if steps < 0:
            raise InputError("steps must be non-negative")
        n = model.dim
        blocks = steps + 1
        self.model = model
        self.steps = steps
        self.f_bar_inv = np.eye(n * blocks)
        for t in range(1, blocks):
            self.f_bar_inv[t * n : (t + 1) * n, (t - 1) * n : t * n] = -model.transition
        self.g_bar = scipy.linalg.block_diag(np.eye(n), *([model.control_matrix] * steps))
        self.w_bar = scipy.linalg.block_diag(model.prior_cov, *([model.process_cov] * steps))
        self.h_bar = np.kron(np.eye(blocks), model.observation_matrix)
        self.v_bar = np.kron(np.eye(blocks), model.observation_cov)

    def lifted_input(self, controls: np.ndarray) -> np.ndarray:
        """``u = [μ₀; u_0; …; u_{T-1}]``."""
        controls = np.asarray(controls, dtype=float).reshape(self.steps, -1)
        return np.concatenate([self.model.prior_mean, controls.ravel()])

    def prior_information(self, controls: np.ndarray) -> InformationGaussian:
        """The lifted prior ``s ~ N(F̄ Ḡ u, F̄ W̄ F̄ᵀ)`` in information form (motion model only)."""
        w_inv = scipy.linalg.block_diag(
            spd_inverse(self.model.prior_cov, "Σ₀"),
            *([spd_inverse(self.model.process_cov, "W")] * self.steps),
        )
        whitened = w_inv @ self.f_bar_inv
        return InformationGaussian(
            whitened.T @ (self.g_bar @ self.lifted_input(controls)),
            self.f_bar_inv.T @ whitened,
        )

    def information(self, controls: np.ndarray, observations: np.ndarray) -> InformationGaussian:
        """The local posterior (17) in information form."""
        observations = np.asarray(observations, dtype=float)
        if observations.shape != (self.steps + 1, self.model.observation_matrix.shape[0]):
            raise InputError(
                f"observations must be (T + 1, m) = ({self.steps + 1}, "
                f"{self.model.observation_matrix.shape[0]}), got {observations.shape}"
            )
        prior = self.prior_information(controls)
        ht_vinv = self.model.observation_matrix.T @ spd_inverse(self.model.observation_cov, "V")
        obs_info = np.kron(np.eye(self.steps + 1), ht_vinv @ self.model.observation_matrix)
        return InformationGaussian(
            prior.info_vector + (observations @ ht_vinv.T).ravel(),
            prior.info_matrix + obs_info,
        )


def local_posterior(
    model: LinearGaussianModel, controls: np.ndarray, observations: np.ndarray
) -> InformationGaussian:
    """Agent's local posterior ``p_i(s_i | u_i, z_i)`` over the lifted state (eq. 17)."""
    steps = np.asarray(observations).shape[0] - 1
    return LiftedModel(model, steps).information(controls, observations)


def lifted_common_index(model: LinearGaussianModel, steps: int) -> np.ndarray:
    """Indices of ``y_0, …, y_T`` inside the lifted state ``[s_0; …; s_T]``."""
    return (np.arange(steps + 1)[:, None] * model.dim + model.common_index[None, :]).ravel()


def split_common_prior(model: LinearGaussianModel, agents: int) -> LinearGaussianModel:
    """Share the common block's prior out among ``agents`` agents.

    Scales the common block's prior and process covariances by ``agents`` so that each agent's
    local posterior carries ``1/agents`` of the prior on ``y``: the product of all agents'
    local posteriors is then the centralised posterior, which the mirror descent converges to.
    Requires ``y``'s dynamics and noise to be independent of ``x``.
    """
    ix, iy = np.arange(model.private_dim), model.common_index
    if (
        np.any(model.transition[np.ix_(iy, ix)])
        or np.any(model.process_cov[np.ix_(ix, iy)])
        or np.any(model.prior_cov[np.ix_(ix, iy)])
    ):
        raise InputError("split_common_prior needs y's dynamics and noise independent of x")
    scale = np.ones(model.dim)
    scale[iy] = float(agents)
    root = np.sqrt(scale)
    return LinearGaussianModel(
        transition=model.transition,
        control_matrix=model.control_matrix,
        process_cov=model.process_cov * np.outer(root, root),
        observation_matrix=model.observation_matrix,
        observation_cov=model.observation_cov,
        prior_mean=model.prior_mean,
        prior_cov=model.prior_cov * np.outer(root, root),
        common_dim=model.common_dim,
    )


def mirror_descent_step(
    states: Sequence[InformationGaussian],
    local: Sequence[InformationGaussian],
    weights: np.ndarray,
    common_index: np.ndarray,
    alpha: float,
) -> list[InformationGaussian]:
    """One iteration of (16) for every agent, in information form (eq. 42).

    Parameters
    ----------
    states
        Each agent's current ``q_i⁽ᵏ⁾`` over its lifted state.
    local
        Each agent's local posterior information ``(Λ_i, λ_i)`` (17).
    weights
        ``(n, n)`` doubly-stochastic weights of this iteration (zero off the surviving edges).
    common_index
        Indices of the common block inside every agent's lifted state (same for all agents).
    alpha
        Step size ``α_k > 0``.
    """
    marginals = [s.marginal(common_index) for s in states]
    block = np.ix_(common_index, common_index)
    out = []
    for i, (state, loc) in enumerate(zip(states, local, strict=True)):
        neighbours = np.flatnonzero(weights[i])
        # every agent holds all of y: eq. 19 is the weighted sum of the marginals (ours
        # included), which replaces our own marginal — one term of eq. 42 with weight one
        average = (
            sum(weights[i, j] * marginals[j].info_matrix for j in neighbours),
            sum(weights[i, j] * marginals[j].info_vector for j in neighbours),
        )
        own = (marginals[i].info_matrix, marginals[i].info_vector)
        omega = state.info_matrix.copy()
        eta = state.info_vector.copy()
        add_weighted_difference(omega, eta, block, common_index, 1.0, average, own)
        out.append(_descent(eta, omega, state, loc, alpha))
    return out


def _descent(
    eta: np.ndarray,
    omega: np.ndarray,
    state: InformationGaussian,
    loc: InformationGaussian,
    alpha: float,
) -> InformationGaussian:
    """Eq. 16 after the average ``(η, Ω)``: ``(η, Ω) + α (local − state)``."""
    return InformationGaussian(
        eta + alpha * (loc.info_vector - state.info_vector),
        omega + alpha * (loc.info_matrix - state.info_matrix),
    )


def mirror_descent_step_moment(
    states: Sequence[InformationGaussian],
    local: Sequence[InformationGaussian],
    weights: np.ndarray,
    common_index: np.ndarray,
    alpha: float,
) -> list[InformationGaussian]:
    """The same iteration written as the paper states it: eq. 15, Prop. 2, then eq. 16."""
    moments = [s.moment() for s in states]
    out = []
    for i, (state, loc) in enumerate(zip(states, local, strict=True)):
        neighbours = np.flatnonzero(weights[i])
        average = geometric_average(
            [moments[j].marginal(common_index) for j in neighbours], weights[i, neighbours]
        )
        rebuilt = moments[i].replace_marginal(common_index, average).information()
        out.append(_descent(rebuilt.info_vector, rebuilt.info_matrix, state, loc, alpha))
    return out


def mirror_descent(
    initial: Sequence[InformationGaussian],
    local: Sequence[InformationGaussian],
    common_index: np.ndarray,
    iterations: int,
    weights: Callable[[int], np.ndarray] | np.ndarray,
    step_size: Callable[[int], float] | float = 1.0,
) -> tuple[list[InformationGaussian], list[float]]:
    """Run ``iterations`` of distributed mirror descent.

    Parameters
    ----------
    initial
        ``q_i⁽⁰⁾`` for every agent (e.g. the lifted priors).
    local
        Local posterior information of every agent (17).
    common_index
        Indices of the common block inside the lifted state.
    iterations
        Number of iterations.
    weights
        A fixed doubly-stochastic matrix, or ``k -> A⁽ᵏ⁾`` (e.g. drawn by
        :class:`~teamslam.graph.EdgeLoss`).
    step_size
        A fixed ``α`` or ``k -> α_k``.

    Returns
    -------
    states, disagreement
        The final states and, per iteration, the largest distance between two agents'
        common-block means.
    """
    states = list(initial)
    disagreement = []
    for k in range(iterations):
        a = weights(k) if callable(weights) else weights
        alpha = step_size(k) if callable(step_size) else step_size
        states = mirror_descent_step(states, local, a, common_index, alpha)
        means = np.stack([s.marginal(common_index).moment().mean for s in states])
        disagreement.append(_max_pairwise_distance(means))
    return states, disagreement


def _max_pairwise_distance(points: np.ndarray) -> float:
    diff = points[:, None, :] - points[None, :, :]
    return float(np.sqrt((diff**2).sum(-1)).max())


def centralized_lifted_posterior(
    models: Sequence[LinearGaussianModel],
    controls: Sequence[np.ndarray],
    observations: Sequence[np.ndarray],
) -> tuple[Gaussian, list[np.ndarray]]:
    """The posterior over all agents' lifted states with one shared copy of ``y``.

    Adds up every agent's local information (17), embedded in the joint lifted state whose
    per-step block is ``[x_{1,t}; …; x_{n,t}; y_t]``. With :func:`split_common_prior`-ed models
    this is the exact centralised posterior.

    Returns
    -------
    posterior, index_maps
        The joint Gaussian and, per agent, where its lifted state sits inside the joint.
    """
    steps = np.asarray(observations[0]).shape[0] - 1
    private = [m.private_dim for m in models]
    n_y = models[0].common_dim
    block = sum(private) + n_y
    offsets = np.concatenate([[0], np.cumsum(private)])
    dim = block * (steps + 1)
    info_matrix = np.zeros((dim, dim))
    info_vector = np.zeros(dim)
    maps = []
    for i, (m, u, z) in enumerate(zip(models, controls, observations, strict=True)):
        per_step = np.concatenate(
            [offsets[i] + np.arange(private[i]), offsets[-1] + np.arange(n_y)]
        )
        index = (np.arange(steps + 1)[:, None] * block + per_step[None, :]).ravel()
        loc = local_posterior(m, u, z)
        info_matrix[np.ix_(index, index)] += loc.info_matrix
        info_vector[index] += loc.info_vector
        maps.append(index)
    return InformationGaussian(info_vector, info_matrix).moment(), maps
