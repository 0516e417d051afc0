"""The loop's reaction in sensor time: for every exposure command, when the light it reacts to was seen and
when the camera first exposed with it.

NEC exists to set a frame's exposure from the events seen before that frame starts. Whether a loop does is a
question of sensor time, not of processing time: a command computed in 100 µs is still late if the camera
has meanwhile streamed ahead (a queue of old data, a device that applies it frames later). For each command a
lane issues, :class:`ReactionMeter` keeps

* ``cause_us``: the sensor time of the packet that caused it (the last event of the batch, an exposure
  marker's time, a frame's exposure end);
* ``applied_us``: the start of the first exposure that used it — the first frame starting at or after
  ``cause_us`` whose exposure and gain match the command (within :data:`TOLERANCE_US` /
  :data:`TOLERANCE_REL`; the newest matching command wins, so a command replaced before any frame used it
  is *superseded*, not applied);
* ``frames_late``: how many exposures started strictly between ``cause_us`` and ``applied_us`` (0: the
  very next exposure used it).

A command that repeats the setting of the previous one changes nothing for the camera and is not a new
change to wait for: it is counted (``commands``) but not tracked (``changes`` counts the others). The match
is made on what the frames report (their exposure and gain), so it needs nothing from the source and holds
for the simulator and a DAVIS alike. An open-loop lane (a replay: the recorded frames do not follow the
commands) has its commands counted and is reported as open loop, never matched to frames.

Memory is bounded: at most :data:`PENDING` changes wait for a frame (older ones count as superseded),
the last :data:`STARTS` exposure starts are kept, ``frames_late`` is counted per value and
``command_to_exposure_us`` goes into a fixed-size histogram.
"""

from __future__ import annotations

import math
from collections import deque

from necviz.telemetry import LatencyHistogram

#: a frame's exposure matches a command's within this many µs ...
TOLERANCE_US = 5.0
#: ... or this fraction of the command's exposure, whichever is larger (gain: this fraction alone)
TOLERANCE_REL = 2e-3
#: changes waiting for a frame that uses them
PENDING = 256
#: exposure starts kept to count the frames between a command's cause and its exposure
STARTS = 4096


class ReactionMeter:
    """Sensor-time reaction of one lane (see the module docstring).

    Parameters
    ----------
    limits : optional
        The camera's :class:`~necviz.core.control.controller.CameraLimits`: commands are clamped to them
        before matching (what the camera will actually use).
    """

    def __init__(self, limits=None):
        self.limits = limits
        self._starts: deque[int] = deque(maxlen=STARTS)
        self._n_starts = 0  # starts ever seen
        self._pending: deque[list] = deque(maxlen=PENDING)  # [cause_us, exposure_us, gain, starts seen]
        self._last: tuple[float, float] | None = None
        self.commands = 0
        self.open_loop = False
        self.changes = 0
        self.applied = 0
        self.superseded = 0
        self.late_counts: dict[int, int] = {}
        self.to_exposure = LatencyHistogram()

    # -- stream -----------------------------------------------------------------------------------
    def start(self, t_us: int) -> None:
        """An exposure started at ``t_us`` (stream order)."""
        t = int(t_us)
        if self._starts and t <= self._starts[-1]:
            return  # seen already (a frame repeats its marker's start)
        self._starts.append(t)
        self._n_starts += 1

    def command(self, cause_us: int, exposure_us: float, gain: float, applies: bool = True) -> None:
        """The lane issued a command caused by the packet of sensor time ``cause_us``; ``applies=False``: an
        open-loop lane (a replay), whose commands never reach the camera — counted, not waited for."""
        self.commands += 1
        if not applies:
            self.open_loop = True
            return
        exp, g = float(exposure_us), float(gain)
        if self.limits is not None:
            exp, g = self.limits.clamp(exp, g)
        if self._last is not None and self._same(self._last, exp, g):
            return
        self._last = (exp, g)
        self.changes += 1
        if len(self._pending) == self._pending.maxlen:
            self.superseded += 1
        self._pending.append([int(cause_us), exp, g, self._n_starts])

    def frame(self, exposure_start_us: int, exposure_us: float, gain: float) -> None:
        """A frame exposed from ``exposure_start_us`` for ``exposure_us`` with ``gain`` arrived."""
        s = int(exposure_start_us)
        self.start(s)
        chosen = None
        for i in range(len(self._pending) - 1, -1, -1):
            c = self._pending[i]
            if c[0] <= s and self._same((c[1], c[2]), float(exposure_us), float(gain)):
                chosen = i
                break
        if chosen is None:
            return
        cause, _, _, seen = self._pending[chosen]
        for _ in range(chosen + 1):
            self._pending.popleft()
        self.superseded += chosen
        k = self._index(s)
        late = max(k - seen, 0) if k is not None else 0
        self.applied += 1
        self.late_counts[late] = self.late_counts.get(late, 0) + 1
        self.to_exposure.add(float(s - cause))

    def _index(self, s: int) -> int | None:
        """The number of exposure starts before the one at ``s`` (None if it is no longer kept)."""
        st = self._starts
        for j in range(len(st) - 1, -1, -1):
            if st[j] == s:
                return self._n_starts - len(st) + j
            if st[j] < s:
                break
        return None

    @staticmethod
    def _same(setting: tuple[float, float], exposure_us: float, gain: float) -> bool:
        e, g = setting
        return abs(exposure_us - e) <= max(TOLERANCE_US, TOLERANCE_REL * e) and abs(gain - g) <= TOLERANCE_REL * g

    # -- summary ----------------------------------------------------------------------------------
    def late_percentile(self, q: float) -> float:
        """The ``q``-th percentile of ``frames_late`` over the applied commands (NaN if none)."""
        n = sum(self.late_counts.values())
        if n == 0:
            return math.nan
        rank = max(q / 100.0 * n, 1)
        seen = 0
        for v in sorted(self.late_counts):
            seen += self.late_counts[v]
            if seen >= rank:
                return float(v)
        return float(max(self.late_counts))

    def summary(self) -> dict:
        """JSON-ready: counts, ``frames_late`` p50/p99/max and ``command_to_exposure_us`` p50/p99/max."""

        def num(v):
            return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v

        h = self.to_exposure
        return {
            "commands": self.commands,
            "open_loop": self.open_loop,
            "changes": self.changes,
            "applied": self.applied,
            "superseded": self.superseded,
            "pending": len(self._pending),
            "frames_late": {
                "p50": num(self.late_percentile(50)),
                "p99": num(self.late_percentile(99)),
                "max": max(self.late_counts) if self.late_counts else None,
            },
            "command_to_exposure_us": {
                "p50": num(h.percentile(50)),
                "p99": num(h.percentile(99)),
                "max": num(h.max_us),
            },
        }


__all__ = ["PENDING", "STARTS", "TOLERANCE_REL", "TOLERANCE_US", "ReactionMeter"]
