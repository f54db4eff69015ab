"""Linear-Gaussian agent models (eq. 10) and a generated team tracking problem.

Each agent ``i`` holds ``s_{i,t} = [x_{i,t}; y_t]`` — private part first, the common part
(landmarks shared by the team) last — with linear-Gaussian motion and observation (eq. 10).
:func:`tracking_problem` generates a team of constant-velocity agents with weak position fixes
sharing slowly drifting planar landmarks, each agent seeing only some of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from teamslam.errors import InputError
from teamslam.gaussian import NotPositiveDefiniteError, symmetrize

__all__ = ["LinearGaussianModel", "TeamProblem", "tracking_problem"]


def _require_spd(matrix: np.ndarray, what: str) -> np.ndarray:
    matrix = symmetrize(np.asarray(matrix, dtype=float))
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError as exc:
        raise NotPositiveDefiniteError(f"{what} is not positive definite") from exc
    return matrix


@dataclass(frozen=True)
class LinearGaussianModel:
    """Time-invariant linear-Gaussian model of one agent over ``s = [x; y]`` (eq. 10).

    Attributes
    ----------
    transition, control_matrix, process_cov
        ``F (n, n)``, ``G (n, p)``, ``W (n, n)`` (positive definite).
    observation_matrix, observation_cov
        ``H (m, n)``, ``V (m, m)`` (positive definite).
    prior_mean, prior_cov
        ``N(μ₀, Σ₀)`` of ``s_0``.
    common_dim
        Size of the common block ``y`` (the last ``common_dim`` entries of ``s``).
    """

    transition: np.ndarray
    control_matrix: np.ndarray
    process_cov: np.ndarray
    observation_matrix: np.ndarray
    observation_cov: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    common_dim: int

    def __post_init__(self) -> None:
        n = np.asarray(self.prior_mean).size
        checks = {
            "transition": (n, n),
            "process_cov": (n, n),
            "prior_cov": (n, n),
        }
        for name, shape in checks.items():
            if np.shape(getattr(self, name)) != shape:
                raise InputError(f"LinearGaussianModel.{name} must be {shape}")
        g = np.asarray(self.control_matrix)
        h = np.asarray(self.observation_matrix)
        if g.ndim != 2 or g.shape[0] != n:
            raise InputError(f"LinearGaussianModel.control_matrix must have {n} rows")
        if h.ndim != 2 or h.shape[1] != n:
            raise InputError(f"LinearGaussianModel.observation_matrix must have {n} columns")
        if np.shape(self.observation_cov) != (h.shape[0], h.shape[0]):
            raise InputError("LinearGaussianModel.observation_cov does not match H")
        if not 0 <= self.common_dim <= n:
            raise InputError(f"common_dim {self.common_dim} outside 0..{n}")
        object.__setattr__(self, "process_cov", _require_spd(self.process_cov, "W"))
        object.__setattr__(self, "observation_cov", _require_spd(self.observation_cov, "V"))
        object.__setattr__(self, "prior_cov", _require_spd(self.prior_cov, "Σ₀"))

    @property
    def dim(self) -> int:
        """Size of ``s``."""
        return self.prior_mean.size

    @property
    def private_dim(self) -> int:
        """Size of the private block ``x``."""
        return self.dim - self.common_dim

    @property
    def common_index(self) -> np.ndarray:
        """Indices of ``y`` inside ``s``."""
        return np.arange(self.private_dim, self.dim)


@dataclass
class TeamProblem:
    """A generated team problem: models, inputs, observations and ground truth.

    Attributes
    ----------
    agents
        One :class:`LinearGaussianModel` per agent over ``[x_i; y]``.
    centralized
        The model over ``[x_1; …; x_n; y]`` that a single filter with all data would use.
    controls
        ``controls[i]`` is ``(T, p)``: the input of agent ``i`` between each pair of steps.
    observations
        ``observations[i]`` is ``(T + 1, m_i)``: agent ``i``'s measurement at every step.
    truth_private
        ``(n, T + 1, d_x)`` true private states.
    truth_common
        ``(T + 1, d_y)`` true common state.
    observed_landmarks
        ``observed_landmarks[i]`` lists the landmarks agent ``i`` measures.
    """

    agents: list[LinearGaussianModel]
    centralized: LinearGaussianModel
    controls: list[np.ndarray]
    observations: list[np.ndarray]
    truth_private: np.ndarray
    truth_common: np.ndarray
    observed_landmarks: list[list[int]] = field(default_factory=list)

    @property
    def n_agents(self) -> int:
        """Number of agents."""
        return len(self.agents)

    @property
    def steps(self) -> int:
        """Number of transitions ``T`` (there are ``T + 1`` time steps)."""
        return self.truth_common.shape[0] - 1

    def centralized_observations(self) -> np.ndarray:
        """``(T + 1, Σ m_i)`` all agents' observations stacked per step."""
        return np.concatenate(self.observations, axis=1)

    def centralized_controls(self) -> np.ndarray:
        """``(T, Σ p_i)`` all agents' inputs stacked per step."""
        return np.concatenate(self.controls, axis=1)

    def truth_agent(self, agent: int) -> np.ndarray:
        """``(T + 1, n_i)`` true ``s_{i,t} = [x_{i,t}; y_t]``."""
        return np.concatenate([self.truth_private[agent], self.truth_common], axis=1)


def tracking_problem(
    agents: int = 4,
    landmarks: int = 6,
    steps: int = 50,
    seed: int = 0,
    landmarks_per_agent: int | None = None,
    dt: float = 1.0,
    acceleration_std: float = 0.2,
    landmark_drift_std: float = 0.02,
    position_fix_std: float = 3.0,
    relative_std: float = 0.5,
    prior_position_std: float = 5.0,
    prior_velocity_std: float = 1.0,
    prior_landmark_std: float = 10.0,
) -> TeamProblem:
    """Generate a linear-Gaussian team tracking problem with common landmarks.

    Agent ``i`` has private state ``x_i = (p_x, p_y, v_x, v_y)`` under a constant-velocity
    model driven by a known acceleration input plus white acceleration noise; it measures its
    position weakly (``position_fix_std``) and the relative position ``p_ℓ - p_i`` of its
    ``landmarks_per_agent`` landmarks (``relative_std``). Landmark subsets are consecutive
    windows of a ring of landmarks, so neighbouring agents overlap and every landmark is seen
    by somebody. Everything is drawn from the generator seeded with ``seed``.

    Returns
    -------
    TeamProblem
    """
    if agents < 1 or landmarks < 1 or steps < 1:
        raise InputError("agents, landmarks and steps must all be positive")
    per_agent = landmarks_per_agent or max(1, int(np.ceil(2 * landmarks / agents)))
    if not 1 <= per_agent <= landmarks:
        raise InputError(f"landmarks_per_agent must lie in 1..{landmarks}")
    rng = np.random.default_rng(seed)
    n_y = 2 * landmarks

    f_x = np.eye(4)
    f_x[0, 2] = f_x[1, 3] = dt
    g_x = np.array([[0.5 * dt**2, 0], [0, 0.5 * dt**2], [dt, 0], [0, dt]])
    w_x = acceleration_std**2 * g_x @ g_x.T + 1e-4 * np.eye(4)
    w_y = landmark_drift_std**2 * np.eye(n_y)
    prior_x_cov = np.diag([prior_position_std**2] * 2 + [prior_velocity_std**2] * 2)
    prior_y_cov = prior_landmark_std**2 * np.eye(n_y)

    true_y0 = rng.uniform(-30.0, 30.0, n_y)
    # the landmark prior mean is a noisy guess of their true layout, so the prior is honest
    prior_y_mean = true_y0 + prior_landmark_std * rng.standard_normal(n_y)
    observed: list[list[int]] = []
    agent_models: list[LinearGaussianModel] = []
    for i in range(agents):
        start = (i * landmarks) // agents
        seen = sorted({(start + k) % landmarks for k in range(per_agent)})
        observed.append(seen)
        rows = [np.hstack([np.eye(2), np.zeros((2, 2 + n_y))])]
        for ell in seen:
            row = np.zeros((2, 4 + n_y))
            row[:, :2] = -np.eye(2)
            row[:, 4 + 2 * ell : 6 + 2 * ell] = np.eye(2)
            rows.append(row)
        h = np.vstack(rows)
        v = np.diag([position_fix_std**2] * 2 + [relative_std**2] * (2 * len(seen)))
        agent_models.append(
            LinearGaussianModel(
                transition=scipy.linalg.block_diag(f_x, np.eye(n_y)),
                control_matrix=np.vstack([g_x, np.zeros((n_y, 2))]),
                process_cov=scipy.linalg.block_diag(w_x, w_y),
                observation_matrix=h,
                observation_cov=v,
                prior_mean=np.concatenate([np.zeros(4), prior_y_mean]),
                prior_cov=scipy.linalg.block_diag(prior_x_cov, prior_y_cov),
                common_dim=n_y,
            )
        )

    true_x = np.zeros((agents, steps + 1, 4))
    true_y = np.zeros((steps + 1, n_y))
    true_y[0] = true_y0
    for i in range(agents):
        true_x[i, 0] = rng.multivariate_normal(np.zeros(4), prior_x_cov)
    controls = [0.3 * rng.standard_normal((steps, 2)) for _ in range(agents)]
    chol_wx = np.linalg.cholesky(w_x)
    for t in range(steps):
        true_y[t + 1] = true_y[t] + landmark_drift_std * rng.standard_normal(n_y)
        for i in range(agents):
            true_x[i, t + 1] = (
                f_x @ true_x[i, t] + g_x @ controls[i][t] + chol_wx @ rng.standard_normal(4)
            )
    observations = []
    for i, model in enumerate(agent_models):
        s = np.concatenate([true_x[i], true_y], axis=1)
        chol_v = np.linalg.cholesky(model.observation_cov)
        noise = rng.standard_normal((steps + 1, model.observation_matrix.shape[0])) @ chol_v.T
        observations.append(s @ model.observation_matrix.T + noise)

    centralized = _centralize(agent_models)
    return TeamProblem(
        agents=agent_models,
        centralized=centralized,
        controls=controls,
        observations=observations,
        truth_private=true_x,
        truth_common=true_y,
        observed_landmarks=observed,
    )


def _centralize(models: list[LinearGaussianModel]) -> LinearGaussianModel:
    """Stack agent models that share the common block ``y`` into one model over ``[x_1…x_n; y]``.

    The common block's transition, noise and prior are taken from the first agent (all agents
    must agree on them); private blocks and their correlations with ``y`` are kept per agent.
    """
    first = models[0]
    n_y = first.common_dim
    iy = first.common_index
    for m in models:
        ix, jy = np.arange(m.private_dim), m.common_index
        if np.any(m.process_cov[np.ix_(ix, jy)]) or np.any(m.prior_cov[np.ix_(ix, jy)]):
            raise InputError("centralising needs private and common noise/prior uncorrelated")
    for m in models[1:]:
        if m.common_dim != n_y or not np.allclose(
            m.transition[np.ix_(m.common_index, m.common_index)], first.transition[np.ix_(iy, iy)]
        ):
            raise InputError("agents disagree on the common block's dynamics")
    dims_x = [m.private_dim for m in models]
    offsets = np.concatenate([[0], np.cumsum(dims_x)])
    n = offsets[-1] + n_y
    y_slice = slice(offsets[-1], n)

    f = np.zeros((n, n))
    w = np.zeros((n, n))
    p0 = np.zeros((n, n))
    mu0 = np.zeros(n)
    g_blocks, h_rows, v_blocks = [], [], []
    for k, m in enumerate(models):
        xs = slice(offsets[k], offsets[k + 1])
        ix = np.arange(m.private_dim)
        f[xs, xs] = m.transition[np.ix_(ix, ix)]
        f[xs, y_slice] = m.transition[np.ix_(ix, m.common_index)]
        w[xs, xs] = m.process_cov[np.ix_(ix, ix)]
        p0[xs, xs] = m.prior_cov[np.ix_(ix, ix)]
        mu0[xs] = m.prior_mean[ix]
        g = np.zeros((n, m.control_matrix.shape[1]))
        g[xs] = m.control_matrix[ix]
        g_blocks.append(g)
        h = np.zeros((m.observation_matrix.shape[0], n))
        h[:, xs] = m.observation_matrix[:, ix]
        h[:, y_slice] = m.observation_matrix[:, m.common_index]
        h_rows.append(h)
        v_blocks.append(m.observation_cov)
    f[y_slice, y_slice] = first.transition[np.ix_(iy, iy)]
    w[y_slice, y_slice] = first.process_cov[np.ix_(iy, iy)]
    p0[y_slice, y_slice] = first.prior_cov[np.ix_(iy, iy)]
    mu0[y_slice] = first.prior_mean[iy]
    return LinearGaussianModel(
        transition=f,
        control_matrix=np.hstack(g_blocks),
        process_cov=w,
        observation_matrix=np.vstack(h_rows),
        observation_cov=scipy.linalg.block_diag(*v_blocks),
        prior_mean=mu0,
        prior_cov=p0,
        common_dim=n_y,
    )
