"""The detector-team benchmark's split of wrong ids after an absence: a second id of the box's
own object (the revisit named anew) against an id of another object."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from teamslam.eval.tracking import idf1_losses

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _named_anew():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        path = BENCHMARKS / "detector_team.py"
        spec = importlib.util.spec_from_file_location("detector_team", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module._named_anew


def test_revisits_named_anew_are_told_from_another_objects_id():
    # object 1: frames 0-5 as id 10, back at frames 30-33 as id 11 (named anew);
    # object 2: frames 0-5 as id 20, back at frames 30-32 under id 10 (object 1's id)
    frames: list[list[tuple[int, int]]] = [[] for _ in range(34)]
    for f in range(6):
        frames[f] += [(1, 10), (2, 20)]
    for f in range(30, 34):
        frames[f].append((1, 11))
    for f in range(30, 33):
        frames[f].append((2, 10))
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in frames])])
    truth = np.array([t for f in frames for t, _ in f], np.int64)
    hyp = np.array([h for f in frames for _, h in f], np.int64)
    losses = idf1_losses(offsets, truth, hyp, revisit_gap=10)
    assert losses["wrong_revisit"] == 7
    assert _named_anew()(offsets, truth, hyp, revisit_gap=10) == 4
    # within the gap nothing is a revisit
    assert _named_anew()(offsets, truth, hyp, revisit_gap=40) == 0
