"""Did a paced run keep the speed it was asked for? The achieved speed, and a note when it fell behind.

A run asked for ``--speed 1`` (or watched in a viewer) feeds packets at real-time pace; on a busy
machine it may not keep up, and then its latency and recovery times are not real-time figures.
:class:`PaceWatch` notes the wall time of the first packet (when the pipeline's pacing clock starts;
compilation before it does not count), and :func:`pace_note` says, in one phrase, how fast the run
actually went when that was below what was asked.
"""

from __future__ import annotations

import time

from necviz.pipeline import Observer

#: Below this fraction of the asked speed a run is said to have fallen behind.
BEHIND = 0.9
#: Wall seconds before a running figure is shown (the first second is mostly start-up jitter).
SETTLE_S = 2.0


class PaceWatch(Observer):
    """Wall time since the run's first packet (``started``); ``None`` before it."""

    name = "pace"

    def __init__(self) -> None:
        self.wall0: float | None = None

    def started(self, t_us: int, initial: dict) -> None:
        self.wall0 = time.perf_counter()

    def wall_s(self) -> float | None:
        return None if self.wall0 is None else time.perf_counter() - self.wall0


def achieved_speed(sensor_s: float, wall_s: float | None, settle_s: float = 0.0) -> float | None:
    """Sensor seconds per wall second (1 = real time); None before ``settle_s`` of wall time or any sensor time."""
    if wall_s is None or wall_s <= settle_s or wall_s <= 0 or sensor_s <= 0:
        return None
    return sensor_s / wall_s


def pace_note(asked: float | None, sensor_s: float, wall_s: float | None, settle_s: float = 0.0) -> str | None:
    """``"ran at 0.63x real time: latency and recovery are not real-time figures"`` when a paced
    run (``asked``: its speed, None = as fast as possible) went below :data:`BEHIND` of it; else None
    (also before ``settle_s`` wall seconds: a running line waits :data:`SETTLE_S`)."""
    got = achieved_speed(sensor_s, wall_s, settle_s)
    if asked is None or got is None or got >= BEHIND * asked:
        return None
    if asked == 1:
        return f"ran at {got:.2f}x real time: latency and recovery are not real-time figures"
    return f"ran at {got:.2f}x real time, not the {asked:g}x asked: latency and recovery are not paced figures"


__all__ = ["PaceWatch", "achieved_speed", "pace_note"]
