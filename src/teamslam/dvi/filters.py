"""The recursive distributed Kalman filter and its centralised reference.

Distributed-MSCKF paper, end of §IV-C: each agent keeps ``N(μ_i, Σ_i)`` over ``[x_i; y]`` and at
every step averages its marginal of ``y`` with its neighbours' (eq. 15 / 19, Prop. 2), predicts
and updates with its own observations (eqs. 65–67). An agent sees its neighbours only through
the :class:`NeighbourMarginal` messages it is handed. See the concept page *Consensus*
(``docs/concepts/consensus.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from teamslam.dvi.kalman import kalman_predict, kalman_update
from teamslam.dvi.models import LinearGaussianModel, TeamProblem
from teamslam.errors import InputError
from teamslam.gaussian import average_common_marginal
from teamslam.graph import EdgeLoss

__all__ = [
    "CentralizedKalmanFilter",
    "DistributedKalmanFilter",
    "DistributedRun",
    "NeighbourMarginal",
    "run_centralized",
    "run_distributed",
]


@dataclass(frozen=True)
class NeighbourMarginal:
    """What one agent tells a neighbour: the marginal ``N(mean, cov)`` of the common block."""

    sender: int
    mean: np.ndarray
    cov: np.ndarray


class CentralizedKalmanFilter:
    """A Kalman filter over the whole team's state with every agent's data."""

    def __init__(self, model: LinearGaussianModel) -> None:
        self.model = model
        self.mean = model.prior_mean.copy()
        self.cov = model.prior_cov.copy()

    def predict(self, control: np.ndarray) -> None:
        """Propagate one step."""
        m = self.model
        self.mean, self.cov = kalman_predict(
            self.mean, self.cov, m.transition, m.process_cov, control, m.control_matrix
        )

    def update(self, observation: np.ndarray, correlation: np.ndarray | None = None) -> None:
        """Condition on one step's observation."""
        m = self.model
        self.mean, self.cov = kalman_update(
            self.mean, self.cov, m.observation_matrix, observation, m.observation_cov, correlation
        )


class DistributedKalmanFilter:
    """One agent's distributed Kalman filter: consensus averaging, prediction, update."""

    def __init__(self, agent: int, model: LinearGaussianModel) -> None:
        self.agent = agent
        self.model = model
        self.mean = model.prior_mean.copy()
        self.cov = model.prior_cov.copy()

    def message(self) -> NeighbourMarginal:
        """This agent's common-block marginal, as sent to its neighbours."""
        iy = self.model.common_index
        return NeighbourMarginal(self.agent, self.mean[iy].copy(), self.cov[np.ix_(iy, iy)])

    def consensus(
        self, self_weight: float, messages: Sequence[tuple[float, NeighbourMarginal]]
    ) -> None:
        """Average the common marginal with the received ones (eq. 19, Prop. 2)."""
        self.mean, self.cov = average_common_marginal(
            self.mean,
            self.cov,
            self.model.common_index,
            self_weight,
            [(w, m.mean, m.cov) for w, m in messages],
        )

    def predict(self, control: np.ndarray) -> None:
        """Propagate one step with the agent's motion model."""
        m = self.model
        self.mean, self.cov = kalman_predict(
            self.mean, self.cov, m.transition, m.process_cov, control, m.control_matrix
        )

    def update(self, observation: np.ndarray, correlation: np.ndarray | None = None) -> None:
        """Condition on the agent's own observation."""
        m = self.model
        self.mean, self.cov = kalman_update(
            self.mean, self.cov, m.observation_matrix, observation, m.observation_cov, correlation
        )


@dataclass
class DistributedRun:
    """Per-step estimates of a distributed run.

    Attributes
    ----------
    means
        ``means[i]`` is ``(T + 1, n_i)``: agent ``i``'s posterior mean after each step.
    covs
        ``covs[i]`` is ``(T + 1, n_i, n_i)``.
    messages
        Number of messages delivered at each step ``(T + 1,)``.
    """

    means: list[np.ndarray]
    covs: list[np.ndarray]
    messages: np.ndarray


def run_centralized(problem: TeamProblem) -> tuple[np.ndarray, np.ndarray]:
    """Centralised Kalman filter over a team problem: means ``(T+1, n)``, covs ``(T+1, n, n)``."""
    kf = CentralizedKalmanFilter(problem.centralized)
    z = problem.centralized_observations()
    u = problem.centralized_controls()
    means, covs = [], []
    for t in range(problem.steps + 1):
        if t > 0:
            kf.predict(u[t - 1])
        kf.update(z[t])
        means.append(kf.mean)
        covs.append(kf.cov)
    return np.stack(means), np.stack(covs)


def run_distributed(
    problem: TeamProblem, edge_loss: EdgeLoss, consensus: bool = True
) -> DistributedRun:
    """Run every agent's distributed Kalman filter in lock-step over a team problem.

    At each step ``t ≥ 1`` the surviving edges and their weights come from ``edge_loss``;
    every agent publishes its common marginal, then averages those of the neighbours it can
    hear (step 1), predicts (2) and updates (3). At ``t = 0`` agents only update.
    """
    n = problem.n_agents
    if edge_loss.graph.n != n:
        raise InputError(f"graph has {edge_loss.graph.n} robots, problem has {n} agents")
    filters = [DistributedKalmanFilter(i, m) for i, m in enumerate(problem.agents)]
    means = [np.empty((problem.steps + 1, m.dim)) for m in problem.agents]
    covs = [np.empty((problem.steps + 1, m.dim, m.dim)) for m in problem.agents]
    delivered = np.zeros(problem.steps + 1, dtype=int)
    for t in range(problem.steps + 1):
        if t > 0:
            active, weights = edge_loss.step()
            if consensus:
                outbox = [f.message() for f in filters]
                for i, f in enumerate(filters):
                    heard = [(weights[i, j], outbox[j]) for j in np.flatnonzero(active[i])]
                    delivered[t] += len(heard)
                    f.consensus(weights[i, i], heard)
            for i, f in enumerate(filters):
                f.predict(problem.controls[i][t - 1])
        for i, f in enumerate(filters):
            f.update(problem.observations[i][t])
            means[i][t] = f.mean
            covs[i][t] = f.cov
    return DistributedRun(means, covs, delivered)
