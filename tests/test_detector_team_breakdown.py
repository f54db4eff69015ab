"""The detector-team benchmark's split of wrong ids after an absence (a second id of the box's
own object, the revisit named anew, against an id of another object) and its measure of a box's
appearance against its own object's summary within a pass and after an absence."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from teamslam.eval.tracking import idf1_losses

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _benchmark():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        path = BENCHMARKS / "detector_team.py"
        spec = importlib.util.spec_from_file_location("detector_team", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


def _named_anew():
    return _benchmark()._named_anew


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


def _unit(angle: float) -> np.ndarray:
    return np.array([np.cos(angle), np.sin(angle), 0.0, 0.0])


def _team(angle: float):
    """One robot: object 1 (class 0) at frames 0-5 looking ``_unit(0)``, back at frames 20-27
    looking ``_unit(angle)``; object 2 (class 0) at every frame looking ``_unit(π/2)``; object 3
    (class 1) at every frame looking exactly as object 1 does when it is back."""
    frames: list[list[tuple[int, int, np.ndarray]]] = [[] for _ in range(28)]
    for f in range(28):
        if f <= 5 or f >= 20:
            frames[f].append((1, 0, _unit(0.0 if f <= 5 else angle)))
        frames[f].append((2, 0, _unit(np.pi / 2)))
        frames[f].append((3, 1, _unit(angle)))
    rows = [r for f in frames for r in f]
    detections = SimpleNamespace(
        offsets=np.concatenate([[0], np.cumsum([len(f) for f in frames])]),
        truth=np.array([t for t, _, _ in rows], np.int64),
        classes=np.array([c for _, c, _ in rows], np.int64),
        appearance=np.array([a for _, _, a in rows]),
    )
    return SimpleNamespace(robots=[SimpleNamespace(detections=detections)])


def test_a_revisit_is_measured_against_its_objects_summary_from_before_the_absence():
    across = _benchmark()._appearance_across
    for angle, nearest in ((np.pi / 6, 1), (np.pi / 3, 0)):
        rows, note = across(_team(angle), gap=10)
        # within a pass: every box but each pass's first, at distance 0 from its pass's mean
        assert rows[0][1:3] == ["66", "0.000"]
        # after the absence: object 1's 8 boxes against its boxes before it
        assert rows[1][1:3] == ["8", f"{1.0 - np.cos(angle):.3f}"]
        # its pass's first 6 boxes are nearer its own summary than object 2's at 30°, farther
        # at 60°; object 3 looks exactly like them, but is of another class
        assert f"of 1 passes after an absence with at least 6 boxes, in {nearest} " in note
