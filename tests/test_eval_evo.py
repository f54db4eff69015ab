"""Our APE/RPE equal ``evo``'s on the same TUM files (skipped where evo is not installed).

evo is GPL-3 and stays optional: ``pip install evo`` to run this check.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from teamslam.datasets import write_tum
from teamslam.eval.runs import read_trajectory
from teamslam.eval.trajectory import evaluate_team
from teamslam.geometry import se3

evo = pytest.importorskip("evo", reason="evo is not installed (optional: pip install evo)")
from evo.core import metrics, sync  # noqa: E402
from evo.tools import file_interface  # noqa: E402


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A reference path and a drifting, offset, scaled estimate of it, as TUM files."""
    rng = np.random.default_rng(5)
    n = 120
    steps = se3.exp(0.05 * rng.standard_normal((n, 6)) + [0.4, 0.0, 0.05, 0.0, 0.03, 0.08])
    ref = np.empty((n, 4, 4))
    ref[0] = np.eye(4)
    for k in range(1, n):
        ref[k] = ref[k - 1] @ steps[k]
    noisy = steps @ se3.exp(0.01 * rng.standard_normal((n, 6)))
    est = np.empty_like(ref)
    est[0] = se3.exp(np.array([1.0, -2.0, 0.5, 0.1, 0.2, 0.3]))
    for k in range(1, n):
        est[k] = est[k - 1] @ noisy[k]
    est[:, :3, 3] *= 1.3
    root = tmp_path_factory.mktemp("evo")
    stamps = 100.0 + 0.1 * np.arange(n)
    write_tum(root / "ref.tum", ref, stamps)
    write_tum(root / "est.tum", est, stamps + 0.002)  # associated within 10 ms
    return root / "est.tum", root / "ref.tum"


def _evo(files, align: str):
    ref = file_interface.read_tum_trajectory_file(str(files[1]))
    est = file_interface.read_tum_trajectory_file(str(files[0]))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    est = copy.deepcopy(est)
    if align in ("se3", "sim3"):
        est.align(ref, correct_scale=align == "sim3")
    elif align == "first-pose":
        est.align_origin(ref)
    return ref, est


def _check(ours: dict, theirs: dict) -> None:
    for stat in ("rmse", "mean", "median", "std", "max", "min"):
        assert ours[stat] == pytest.approx(theirs[stat], rel=1e-9, abs=1e-12), stat


@pytest.mark.parametrize("align", ["none", "se3", "sim3", "first-pose"])
def test_ape_and_rpe_equal_evo(files, align):
    ref, est = _evo(files, align)
    ours = evaluate_team(
        [read_trajectory(files[0])],
        [read_trajectory(files[1])],
        align=align,
        scope="robot",
        rpe_delta=3,
        rpe_unit="frames",
    ).statistics()["robots"][0]
    for relation, key in (
        (metrics.PoseRelation.translation_part, "ape_translation_m"),
        (metrics.PoseRelation.rotation_angle_deg, "ape_rotation_deg"),
    ):
        ape = metrics.APE(relation)
        ape.process_data((ref, est))
        _check(ours[key], ape.get_all_statistics())
    for relation, key in (
        (metrics.PoseRelation.translation_part, "rpe_translation_m"),
        (metrics.PoseRelation.rotation_angle_deg, "rpe_rotation_deg"),
    ):
        rpe = metrics.RPE(relation, delta=3, delta_unit=metrics.Unit.frames, all_pairs=True)
        rpe.process_data((ref, est))
        _check(ours[key], rpe.get_all_statistics())
