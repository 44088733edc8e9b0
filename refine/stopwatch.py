"""Stage timing: wall and CPU time per stage.

:class:`StageTimes` and :func:`add_time` keep the optimiser's stages (seed, solve, verify, build), with
the process CPU time beside the wall time; :class:`Stopwatch` laps the stages of a whole run. Both
feed ``result.json``'s ``timings_s``.
"""

from __future__ import annotations

import time

from refine.control import stage_done


class StageTimes(dict):
    """Wall time per stage [s] (the dict itself), with the process CPU time of the same stages in ``cpu``."""

    def __init__(self) -> None:
        super().__init__()
        self.cpu: dict[str, float] = {}

    @staticmethod
    def clock() -> tuple[float, float]:
        """The wall and CPU clocks now."""
        return time.perf_counter(), time.process_time()


def add_time(timings: dict[str, float], key: str, start: tuple[float, float]) -> None:
    """Add the wall time since ``start`` (:meth:`StageTimes.clock`) to stage ``key`` of ``timings``.

    The CPU time goes to ``timings.cpu`` where ``timings`` is a :class:`StageTimes`.
    """
    timings[key] = timings.get(key, 0.0) + time.perf_counter() - start[0]
    if isinstance(timings, StageTimes):
        timings.cpu[key] = timings.cpu.get(key, 0.0) + time.process_time() - start[1]


class Stopwatch:
    """Wall time per stage of a run, lapped stage after stage."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        """Add the time since the last lap to stage ``name``; tell the call's host (:mod:`refine.control`).

        Raises:
            refine.errors.Cancelled: the host asked the call to stop.
        """
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now
        stage_done(name)

    def add(self, times: dict[str, float]) -> None:
        """Add the times [s] of stages timed elsewhere."""
        for stage, seconds in times.items():
            self.times[stage] = self.times.get(stage, 0.0) + seconds
