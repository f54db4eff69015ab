import numpy as np

import teamslam as ts
from teamslam.eval.metrics import team_metrics
from teamslam.geometry import se3

# Lie groups, batched over leading axes; right perturbation T = T̂ · exp(ε^), ε = (ρ, φ)
T = se3.exp(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.3]))
J = se3.right_jacobian(se3.log(T))

# consensus on a common block: average neighbours' marginals (eq. 19), rebuild the joint (Prop. 2)
joint = ts.gaussian.Gaussian(np.zeros(5), np.eye(5))
common = [3, 4]
neighbour = ts.gaussian.Gaussian(np.ones(2), 2 * np.eye(2))
average = ts.gaussian.geometric_average([joint.marginal(common), neighbour], [0.5, 0.5])
joint = joint.replace_marginal(common, average)

# a linear-Gaussian team problem: the distributed Kalman filter over a lossy ring, and the
# centralised one
problem = ts.dvi.tracking_problem(agents=4, landmarks=6, steps=50, seed=0)
graph = ts.graph.ring(4)
run = ts.dvi.run_distributed(problem, ts.graph.EdgeLoss(graph, rate=0.3, seed=0))
central_means, central_covs = ts.dvi.run_centralized(problem)

# a simulated stereo team and the distributed MSCKF, separate vs consensus
team = ts.sim.lissajous_team(robots=3, steps=30, seed=0)
config = ts.msckf.config_for(team, {"filter.window": 8})  # the sensor model the simulator recorded
results = {}
for consensus in (False, True):
    results[consensus] = ts.run_team(team, config, graph=ts.graph.complete(3), consensus=consensus)
    metrics = team_metrics(team, results[consensus])
    print(consensus, metrics["trajectory_rmse_avg_m"], metrics["object_disagreement_avg_m"])
