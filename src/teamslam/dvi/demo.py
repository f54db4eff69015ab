"""The ``teamslam dvi-demo`` job: distributed vs separate vs centralised Kalman filtering.

Generates a :func:`~teamslam.dvi.models.tracking_problem`, runs on the same data

* the centralised Kalman filter (every observation, one filter),
* the distributed Kalman filter (consensus over the communication graph, with edge loss),
* the same agents without consensus ("separate"),

and reports per-agent errors, inter-agent disagreement on the common landmarks, distance to
the centralised estimate, and NEES.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from teamslam.dvi.filters import DistributedRun, run_centralized, run_distributed
from teamslam.dvi.models import TeamProblem, tracking_problem
from teamslam.gaussian import nees
from teamslam.graph import EdgeLoss, make

__all__ = ["DemoResult", "run_demo"]


@dataclass
class DemoResult:
    """Everything the demo measured; :meth:`metrics` is what goes to ``metrics.json``."""

    agents: int
    graph: str
    loss: float
    steps: int
    seed: int
    landmark_error: dict[str, np.ndarray]  # filter -> (T + 1, n) or (T + 1,) landmark RMSE
    position_error: dict[str, np.ndarray]  # filter -> (T + 1, n) own-position error
    disagreement: dict[str, np.ndarray]  # filter -> (T + 1,) max pairwise common-mean distance
    error_vs_centralized: dict[str, np.ndarray]  # filter -> (T + 1, n)
    common_nees: dict[str, np.ndarray]  # filter -> (T + 1, n) NEES of the common block
    messages: int = 0
    extra: dict = field(default_factory=dict)

    def metrics(self) -> dict:
        """JSON-ready summary."""
        dist = "distributed"
        return {
            "agents": self.agents,
            "graph": self.graph,
            "loss": self.loss,
            "steps": self.steps,
            "seed": self.seed,
            "final_disagreement": float(self.disagreement[dist][-1]),
            "final_disagreement_separate": float(self.disagreement["separate"][-1]),
            "max_error_vs_centralized": float(self.error_vs_centralized[dist].max()),
            "max_error_vs_centralized_separate": float(self.error_vs_centralized["separate"].max()),
            "landmark_rmse_final": {
                k: float(np.mean(v[-1])) for k, v in self.landmark_error.items()
            },
            "position_rmse": {
                k: float(np.sqrt(np.mean(v**2))) for k, v in self.position_error.items()
            },
            "common_nees_avg": {k: float(np.mean(v)) for k, v in self.common_nees.items()},
            "common_dim": int(self.extra["common_dim"]),
            "messages_delivered": int(self.messages),
        }

    def table(self, rows: int = 10) -> str:
        """Per-step comparison table followed by a per-filter summary."""
        n = self.agents
        picks = np.unique(np.linspace(0, self.steps, min(rows, self.steps + 1)).astype(int))
        head = (
            f"{'step':>5} | {'central':>8} | "
            + " ".join(f"{'a' + str(i):>7}" for i in range(n))
            + f" | {'disagree':>8} | {'vs cent':>8} | {'sep dis':>8}"
        )
        lines = [
            f"dvi-demo: {n} agents, graph {self.graph}, loss {self.loss}, "
            f"{self.steps} steps, seed {self.seed}",
            "landmark RMSE [m] per agent (distributed filter), max disagreement between agents,",
            "max distance to the centralised estimate, and the separate filters' disagreement",
            head,
            "-" * len(head),
        ]
        for t in picks:
            lines.append(
                f"{t:>5} | {self.landmark_error['centralized'][t]:8.3f} | "
                + " ".join(f"{e:7.3f}" for e in self.landmark_error["distributed"][t])
                + f" | {self.disagreement['distributed'][t]:8.3f}"
                + f" | {self.error_vs_centralized['distributed'][t].max():8.3f}"
                + f" | {self.disagreement['separate'][t]:8.3f}"
            )
        m = self.metrics()
        lines += [
            "",
            f"{'filter':<12} | {'landmark RMSE':>13} | {'position RMSE':>13} | "
            f"{'final disagree':>14} | {'max vs central':>14} | {'common NEES':>11}",
        ]
        d = m["common_dim"]
        for name in ("centralized", "distributed", "separate"):
            dis = self.disagreement.get(name)
            vs = self.error_vs_centralized.get(name)
            lines.append(
                f"{name:<12} | {m['landmark_rmse_final'][name]:13.3f} | "
                f"{m['position_rmse'][name]:13.3f} | "
                + (f"{dis[-1]:14.3f}" if dis is not None else f"{'-':>14}")
                + " | "
                + (f"{vs.max():14.3f}" if vs is not None else f"{'-':>14}")
                + f" | {m['common_nees_avg'][name]:11.2f}"
            )
        lines.append(f"(common NEES is χ²({d}) for a consistent filter: mean {d})")
        return "\n".join(lines)


def _summarise(problem: TeamProblem, run: DistributedRun) -> dict[str, np.ndarray]:
    iy = problem.agents[0].common_index
    truth_y = problem.truth_common
    common = np.stack([m[:, iy] for m in run.means], axis=1)  # (T+1, n, d_y)
    landmarks = problem.agents[0].common_dim // 2
    err = np.sqrt(((common - truth_y[:, None, :]) ** 2).sum(-1) / landmarks)
    pos = np.stack(
        [
            np.linalg.norm(m[:, :2] - problem.truth_private[i, :, :2], axis=-1)
            for i, m in enumerate(run.means)
        ],
        axis=1,
    )
    diff = common[:, :, None, :] - common[:, None, :, :]
    dis = np.sqrt((diff**2).sum(-1)).max(axis=(1, 2))
    ne = np.array(
        [
            [
                nees(run.means[i][t, iy], run.covs[i][t][np.ix_(iy, iy)], truth_y[t])
                for i in range(problem.n_agents)
            ]
            for t in range(problem.steps + 1)
        ]
    )
    return {"landmark": err, "position": pos, "disagreement": dis, "common": common, "nees": ne}


def run_demo(
    agents: int = 5,
    graph: str = "ring",
    loss: float = 0.0,
    steps: int = 60,
    seed: int = 0,
    landmarks: int | None = None,
) -> DemoResult:
    """Run the three filters on one generated problem and collect the comparison."""
    landmarks = landmarks or max(4, agents + 1)
    problem = tracking_problem(agents=agents, landmarks=landmarks, steps=steps, seed=seed)
    comm = make(graph, agents, seed=seed)
    central_mean, central_cov = run_centralized(problem)
    distributed = run_distributed(problem, EdgeLoss(comm, loss, seed=seed + 1))
    separate = run_distributed(problem, EdgeLoss(comm, loss, seed=seed + 1), consensus=False)

    n_x = problem.agents[0].private_dim
    n_y = problem.agents[0].common_dim
    cy = slice(agents * n_x, agents * n_x + n_y)
    truth_y = problem.truth_common
    central_err = np.sqrt(((central_mean[:, cy] - truth_y) ** 2).sum(-1) / (n_y // 2))
    central_pos = np.stack(
        [
            np.linalg.norm(
                central_mean[:, i * n_x : i * n_x + 2] - problem.truth_private[i, :, :2], axis=-1
            )
            for i in range(agents)
        ],
        axis=1,
    )
    central_nees = np.array(
        [nees(central_mean[t, cy], central_cov[t][cy, cy], truth_y[t]) for t in range(steps + 1)]
    )
    result = DemoResult(
        agents=agents,
        graph=comm.name,
        loss=loss,
        steps=steps,
        seed=seed,
        landmark_error={"centralized": central_err},
        position_error={"centralized": central_pos},
        disagreement={},
        error_vs_centralized={},
        common_nees={"centralized": central_nees},
        messages=int(distributed.messages.sum()),
        extra={"common_dim": n_y},
    )
    for name, run in (("distributed", distributed), ("separate", separate)):
        s = _summarise(problem, run)
        result.landmark_error[name] = s["landmark"]
        result.position_error[name] = s["position"]
        result.disagreement[name] = s["disagreement"]
        result.error_vs_centralized[name] = np.linalg.norm(
            s["common"] - central_mean[:, None, cy], axis=-1
        )
        result.common_nees[name] = s["nees"]
    return result
