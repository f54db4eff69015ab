"""Object initialisation: the least-squares point of the window, entered once it is certain."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from teamslam.errors import InputError
from teamslam.msckf import MsckfAgent, MsckfConfig, config_for
from teamslam.msckf.filter.linearization import GroundTruth
from teamslam.msckf.filter.models import observe
from teamslam.msckf.filter.state import MsckfState
from teamslam.sim import lissajous_team


@pytest.fixture(scope="module")
def team():
    return lissajous_team(robots=1, steps=40, seed=3, landmarks=300, objects=150)


def _run(team, monkeypatch, linearization="fej", settings=None):
    """Run one robot; record every object entering the state with what it was built from."""
    cfg = config_for(
        team, {"filter.window": 6, "filter.linearization": linearization, **(settings or {})}
    )
    robot = team.robots[0]
    agent = MsckfAgent(0, team.calibration, robot, cfg, truth=GroundTruth(robot.T_world_body, team))
    entered = []
    monkeypatch.undo()  # a previous run's recorders
    original_add = MsckfAgent._add_object
    original_state_add = MsckfState.add_object

    def add(self, oid, point, widx, zs, variance, n, **kwargs):
        self._pending = (self.state.poses[widx].copy(), zs.copy())
        return original_add(self, oid, point, widx, zs, variance, n, **kwargs)

    def state_add(state, oid, position, cov_pp, cov_ps, **kwargs):
        poses, zs = agent._pending
        entered.append((position.copy(), cov_pp.copy(), state.current_pose.copy(), poses, zs))
        original_state_add(state, oid, position, cov_pp, cov_ps, **kwargs)

    monkeypatch.setattr(MsckfAgent, "_add_object", add)
    monkeypatch.setattr(MsckfState, "add_object", state_add)
    for t in range(robot.frames):
        agent.step(t)
    return agent, entered


@pytest.mark.parametrize("linearization", ["std", "fej"])
def test_objects_enter_at_the_least_squares_point_once_certain(team, monkeypatch, linearization):
    """Each object enters at the least-squares point of its observations in the window (the
    poses held fixed; an independent solver agrees — fej's QR step uses its first-estimate
    Jacobians, so there within a quarter of a standard deviation) and only with a
    position std at most ``objects.init_max_relative_std`` of its distance; less certain ones
    wait (for more observations), so without the limit less certain objects enter."""
    only_relative = {"objects.init_max_relative_std": 0.1, "objects.init_linearity_probability": 0}
    agent, entered = _run(team, monkeypatch, linearization, only_relative)
    limit = agent.config.objects.init_max_relative_std
    assert limit == 0.1
    assert len(entered) >= 5 and agent.counters["object_init_deferred"] > 0
    cam = team.calibration.camera
    for position, cov_pp, current, poses, zs in entered:
        distance = np.linalg.norm(position - current[:3, 3])
        assert np.sqrt(np.linalg.eigvalsh(cov_pp)[-1]) <= limit * distance * (1 + 1e-12)

        def residual(p, poses=poses, zs=zs):
            return (observe(cam, team.calibration.T_cam_body, poses, p[None]) - zs).ravel()

        ref = least_squares(residual, position + 0.3, xtol=1e-14, ftol=1e-14, gtol=1e-14).x
        if linearization == "std":
            np.testing.assert_allclose(position, ref, atol=1e-6 * max(1.0, distance))
        else:
            d = position - ref
            assert np.sqrt(d @ np.linalg.solve(cov_pp, d)) < 0.25
    no_wait = {"objects.init_linearity_probability": 0}
    eager, entered_eager = _run(team, monkeypatch, linearization, no_wait)
    assert eager.counters["object_init_deferred"] == 0
    ratios = [
        np.sqrt(np.linalg.eigvalsh(c)[-1]) / np.linalg.norm(p - cur[:3, 3])
        for p, c, cur, _, _ in entered_eager
    ]
    assert max(ratios) > limit


@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf"), True])
def test_object_init_max_relative_std_is_validated(value):
    with pytest.raises(InputError, match=r"objects\.init_max_relative_std"):
        MsckfConfig.from_settings({"objects.init_max_relative_std": value})
