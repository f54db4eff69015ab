"""Where the front-end's CPU time goes: process time summed per named stage.

A :class:`StageClock` is carried by each :class:`~teamslam.frontend.pipeline.StereoFrontend`
(its ``clock``) and handed to the parts it calls; ``benchmarks/frontend_cost.py`` reads it per
frame. Process time (every thread of the process): with one OpenCV and one BLAS thread it is
the stage's own CPU time, whatever else the machine runs. Two clock readings per stage.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["STAGES", "StageClock"]

#: the front-end's stages, in the order a frame goes through them
STAGES = (
    "rectification",
    "temporal LK",
    "track alignment",
    "feature detection",
    "stereo search",
    "stereo LK",
    "stereo alignment",
    "markers",
    "box stereo",
)


class StageClock:
    """CPU seconds per stage, summed over the calls since the clock was made or
    :meth:`reset`: ``seconds[stage]``."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def reset(self) -> dict[str, float]:
        """The seconds so far; the clock starts again from zero."""
        seconds, self.seconds = self.seconds, {}
        return seconds

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Count the CPU time of the block to ``name``."""
        begin = time.process_time()
        try:
            yield
        finally:
            spent = time.process_time() - begin
            self.seconds[name] = self.seconds.get(name, 0.0) + spent
