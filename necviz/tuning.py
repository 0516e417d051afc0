"""Live tuning: change controller parameters while ``demo`` or ``live`` runs, without restarting.

Two ways in, same language:

* a prompt on the terminal (lines typed while the run goes on), and
* a watched file (``--tune-file FILE``): whenever it is saved, every ``key = value`` line that
  changed is applied.

Language (``help`` prints it)::

    [LANE.]KEY = VALUE      e.g.  goal = 100      nec.dead_band = 0.05
    set [LANE.]KEY VALUE
    drive NAME              which controller drives the camera (live only)
    status                  current settings
    help

Keys: ``c_on``, ``c_off``, ``c`` (both; P-TEDI contrast thresholds, ln units), ``dead_band``,
``full_band`` (NEC's f_w corners on |ln(H_opt/H_i)|), ``goal`` (NEC's goal intensity, DN),
``exposure_min``, ``exposure_max`` (µs), ``gain_max`` (linear). Without ``LANE.`` a key applies to
every lane where it means something. A change runs on the streaming thread between two packets;
it is logged to the recording (``tuning`` entity) and to the native recording as an annotation,
so a replay shows when it happened. Bad values are rejected with a one-line reason.
"""

from __future__ import annotations

import math
import os
import re
import sys
import threading
from dataclasses import replace
from pathlib import Path

from . import schema as S
from .core.control import NECController
from .core.errors import ParameterError

KEYS = ("c_on", "c_off", "c", "dead_band", "full_band", "goal", "exposure_min", "exposure_max", "gain_max")
HELP = ("commands: [LANE.]KEY = VALUE | set [LANE.]KEY VALUE | drive NAME | status | help;  keys: "
        + ", ".join(KEYS))

_ASSIGN = re.compile(r"^\s*(?:set\s+)?(?:(?P<lane>[A-Za-z_][\w-]*)\.)?(?P<key>[a-z_]+)\s*(?:=|\s)\s*(?P<value>\S+)\s*$")


class Change:
    """A parsed command; calling it on the pipeline (streaming thread) applies it."""

    def __init__(self, text: str, fn, reply=None):
        self.text = text
        self._fn = fn
        self._reply = reply

    def __call__(self, pipeline):
        return self._fn(pipeline)

    def reply(self, message: str) -> None:
        if self._reply is not None:
            self._reply(message)


def _number(key: str, value: str) -> float:
    try:
        v = float(value)
    except ValueError:
        raise ParameterError(f"{key}: {value!r} is not a number") from None
    if not math.isfinite(v):
        raise ParameterError(f"{key} must be finite, got {value}")
    return v


def _targets(pipeline, lane: str | None):
    if lane is None:
        return list(pipeline.lanes.values())
    if lane not in pipeline.lanes:
        raise ParameterError(f"no lane {lane!r}; lanes: {', '.join(pipeline.lanes)}")
    return [pipeline.lanes[lane]]


def _set(lane_name: str | None, key: str, v: float):
    def apply(pipeline):
        lanes = _targets(pipeline, lane_name)
        touched = []
        if key in ("c_on", "c_off", "c"):
            for lane in lanes:
                p = lane.estimator.params
                new = replace(p, c_on=v, c_off=v) if key == "c" else replace(p, **{key: v})
                lane.estimator.set_params(new)
                touched.append(lane.name)
        elif key in ("dead_band", "full_band", "goal"):
            necs = [lane for lane in lanes if isinstance(lane.controller, NECController)]
            if not necs:
                raise ParameterError(f"{key} is a NEC parameter and no NEC lane is selected")
            for lane in necs:
                c = lane.controller
                if key == "goal":
                    crf = c.estimator.crf
                    if not crf.valid_min < v < crf.valid_max:
                        raise ParameterError(f"goal must lie inside the valid range {crf.valid_min}..{crf.valid_max} DN, got {v:g}")
                    c.goal_log_exposure = float(crf.log_exposure(v))
                else:
                    dead = v if key == "dead_band" else c.dead_band
                    full = v if key == "full_band" else c.full_band
                    if dead < 0 or full <= dead:
                        raise ParameterError(f"need 0 <= dead_band < full_band, got {dead:g} and {full:g}")
                    c.dead_band, c.full_band = dead, full
                touched.append(lane.name)
        else:
            hw = getattr(pipeline.source, "limits", None)  # what the camera itself can do, if it says
            if hw is not None:
                lo, hi = (1.0, hw.gain_max) if key == "gain_max" else (hw.exposure_min_us, hw.exposure_max_us)
                if not lo <= v <= hi:
                    raise ParameterError(f"{key} = {v:g} is outside what the camera accepts ({lo:g}..{hi:g})")
            for lane in lanes:
                lim = lane.controller.limits
                fields = {"exposure_min": "exposure_min_us", "exposure_max": "exposure_max_us", "gain_max": "gain_max"}
                lane.controller.limits = replace(lim, **{fields[key]: v})  # CameraLimits validates
                touched.append(lane.name)
        msg = f"{key} = {v:g} on {', '.join(touched)}"
        return msg, {"tuning": {"key": key, "value": v, "lanes": touched}}

    return apply


def _drive(name: str):
    def apply(pipeline):
        factory = getattr(pipeline, "controller_factory", None)
        if factory is None:
            raise ParameterError("drive: every controller drives its own camera here (use it with necviz live)")
        lane = next(iter(pipeline.lanes.values()))
        old = lane.controller.name
        lane.controller = factory(name, lane.controller)
        if isinstance(lane.controller, NECController):
            lane.estimator, lane.passive_estimator = lane.controller.estimator, False
        else:
            lane.passive_estimator = True
        if pipeline.sink is not None:
            pipeline.sink.text(S.path(lane.name, S.LOG), pipeline.now_us or 0, f"controller: {old} -> {name}")
        return f"{name} now drives {lane.name} (was {old})", {"tuning": {"key": "drive", "value": name}}

    return apply


def status(pipeline) -> str:
    parts = []
    for lane in pipeline.lanes.values():
        c, p, lim = lane.controller, lane.estimator.params, lane.controller.limits
        s = (f"{lane.name}: {c.name}, c_on={p.c_on:g} c_off={p.c_off:g}, exposure {lim.exposure_min_us:g}.."
             f"{lim.exposure_max_us:g} µs, gain_max={lim.gain_max:g}")
        if isinstance(c, NECController):
            goal = float(c.estimator.crf.intensity(c.goal_log_exposure))
            s += f", dead_band={c.dead_band:g} full_band={c.full_band:g} goal={goal:.0f} DN"
        parts.append(s)
    return "; ".join(parts)


def parse(line: str, reply=None) -> Change | None:
    """One command line -> a :class:`Change` (``None`` for blank lines and comments).

    Raises :class:`ParameterError` for lines that are not commands.
    """
    text = line.split("#", 1)[0].strip()
    if not text:
        return None
    if text == "help":
        return Change(text, lambda p: (HELP, None), reply)
    if text == "status":
        return Change(text, lambda p: (status(p), None), reply)
    m = re.fullmatch(r"drive\s+(\w+)", text)
    if m:
        from .core.control import CONTROLLERS

        if m.group(1) not in CONTROLLERS:
            raise ParameterError(f"unknown controller {m.group(1)!r}; available: {', '.join(sorted(CONTROLLERS))}")
        return Change(text, _drive(m.group(1)), reply)
    m = _ASSIGN.match(text)
    if not m or m.group("key") not in KEYS:
        raise ParameterError(f"cannot read {text!r}; {HELP}")
    key = m.group("key")
    return Change(text, _set(m.group("lane"), key, _number(key, m.group("value"))), reply)


class TuningConsole:
    """Reads commands from a text stream (the terminal) on a daemon thread."""

    def __init__(self, pipeline, stream=None, out=None):
        self.pipeline = pipeline
        self.stream = stream if stream is not None else sys.stdin
        self.out = out if out is not None else sys.stderr
        self._thread = threading.Thread(target=self._run, name="necviz-tuning", daemon=True)

    def start(self) -> "TuningConsole":
        self._thread.start()
        return self

    def _say(self, msg: str) -> None:
        print(f"\n  tune: {msg}", file=self.out, flush=True)

    def _run(self) -> None:
        for line in self.stream:
            try:
                change = parse(line, reply=self._say)
            except ParameterError as e:
                self._say(f"error: {e}")
                continue
            if change is not None:
                self.pipeline.submit(change)


class TuningFile:
    """Watches a ``key = value`` file; applies the lines that changed each time it is saved."""

    def __init__(self, pipeline, path: str | Path, out=None, poll_s: float = 0.5):
        self.pipeline = pipeline
        self.path = Path(path)
        if not self.path.is_file():
            raise ParameterError(f"--tune-file: {str(self.path)!r} is not a file")
        self.out = out if out is not None else sys.stderr
        self.poll_s = float(poll_s)
        self._seen: dict[str, str] = {}
        self._mtime = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="necviz-tune-file", daemon=True)

    def start(self) -> "TuningFile":
        self.check()  # the file's current content applies at once
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def check(self) -> int:
        """Apply changed lines if the file changed since the last check; returns how many."""
        try:
            mtime = os.stat(self.path).st_mtime_ns
        except OSError:
            return 0
        if mtime == self._mtime:
            return 0
        self._mtime = mtime
        n = 0
        for line in self.path.read_text(encoding="utf-8", errors="replace").splitlines():
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            key = re.split(r"\s*=\s*|\s+", text.removeprefix("set ").strip(), maxsplit=1)[0]
            if self._seen.get(key) == text:
                continue
            self._seen[key] = text
            try:
                change = parse(text, reply=lambda m: print(f"\n  tune: {m}", file=self.out, flush=True))
            except ParameterError as e:
                print(f"\n  tune: {self.path.name}: error: {e}", file=self.out, flush=True)
                continue
            if change is not None:
                self.pipeline.submit(change)
                n += 1
        return n

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            self.check()


__all__ = ["HELP", "KEYS", "Change", "TuningConsole", "TuningFile", "parse", "status"]
