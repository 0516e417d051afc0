"""The closed loop: source -> controllers -> commands back to the source, on one streaming thread.

A :class:`Pipeline` pulls ``(camera, packet)`` pairs from a :class:`~necviz.drivers.source.Source`
(one camera, or a rig of cameras sharing a scene) and feeds every :class:`Lane` — a controller
watching one camera, driving it unless the run is open loop. NEC owns its P-TEDI estimator; any
other controller gets a *passive* one, so every lane has a prediction to show. A command goes
straight back to the source (``source.set_exposure(camera, exposure_us, gain)``), between frames,
at the rate event batches arrive.

The pipeline only controls. What the frames and commands mean is computed once by a
:class:`~necviz.telemetry.Telemetry`; whoever wants to see the run — the Rerun sink
(:mod:`necviz.dashboard.sink`), the native recorder — is an :class:`Observer`, called with what happened
through methods that only append to memory, so control never waits for them.

Measured per command: the processing latency from the moment the packet that caused it left the
source to the moment the command was handed back (the source's batch period, ≤ 1 ms, comes on
top in sensor time), and the reaction in sensor time — from the packet that caused it to the start of
the first exposure that used it, and the frames that started in between (:mod:`necviz.reaction`,
``stats["lanes"][lane]["reaction"]``). Start-up is not in it: before the first packet, every kernel the lanes and
observers use is compiled or loaded from Numba's cache (:mod:`necviz.warmup`, on copies of the
lanes; ``warm_up=False`` skips it).

Changes while running (live tuning, switching the controller) are submitted from any thread
(:meth:`Pipeline.tune`, :meth:`Pipeline.drive`) and applied on the streaming thread between two
packets; each returns a :class:`~concurrent.futures.Future` with the outcome.

Shutdown: source end, :meth:`Pipeline.stop` (Ctrl-C) or a source error end the streaming thread;
:meth:`Pipeline.finish` closes the source and the observers (flushing recordings) and re-raises
the error if there was one, so what was seen before a fault is kept.
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import Future
from dataclasses import replace
from pathlib import Path

import numpy as np

from necviz import schema as S
from necviz.core.checks import check_number
from necviz.core.control import CONTROLLERS, Controller, ControllerContext, create_controller
from necviz.core.errors import NecvizError, ParameterError, StreamError
from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.stream import packet_time_us
from necviz.dvs_controls import DvsControls
from necviz.outputs import low_space
from necviz.reaction import ReactionMeter
from necviz.telemetry import FrameRecord, Telemetry

#: Thresholds of the lane's P-TEDI estimator, tunable like the controller's own parameters.
THRESHOLD_KEYS = ("c_on", "c_off", "c")


class Lane:
    """A controller watching one camera of the source.

    Parameters
    ----------
    name : the lane's name (its entity root in the recording; unique in a pipeline).
    controller : any :class:`~necviz.core.control.Controller`.
    camera : the source camera it watches (default: ``name`` if the source has such a camera,
        else the source's only camera).
    drives : send its commands to the camera (``False``: open loop, shown only).
    estimator : the P-TEDI estimator fed beside a controller that has none of its own
        (default: one on the source's sensor with default thresholds). NEC uses its own.
    """

    def __init__(
        self,
        name: str,
        controller: Controller,
        camera: str | None = None,
        drives: bool = True,
        estimator: PeripheralEstimator | None = None,
    ):
        if not isinstance(controller, Controller):
            raise ParameterError(f"lane {name!r}: the controller must be a necviz Controller")
        self.name = name
        self.camera = camera
        self.drives = bool(drives)
        self.controller = controller
        self.passive: PeripheralEstimator | None = None if controller.estimator is not None else estimator

    @property
    def estimator(self) -> PeripheralEstimator | None:
        """The P-TEDI estimator whose prediction this lane shows (the controller's own, or the passive one)."""
        return self.passive if self.passive is not None else self.controller.estimator

    def switch(self, controller: Controller) -> None:
        """Let ``controller`` take over; a controller without an estimator inherits the current one."""
        self.passive = self.estimator if controller.estimator is None else None
        self.controller = controller

    def tunables(self) -> list[str]:
        return [*THRESHOLD_KEYS, *self.controller.tunables()]


def _estimator(lane: Lane) -> PeripheralEstimator:
    """The lane's estimator once it is in a :class:`Pipeline` (which gives every lane one)."""
    est = lane.estimator
    assert est is not None  # Pipeline gives a lane without one a passive estimator; switch() keeps it
    return est


class Observer:
    """Something that watches a run (the Rerun sink, the native recorder, the disk watch). Every method
    is called on the streaming thread and must only append to memory (or, rarely, ask the system: the
    disk watch's ``statvfs`` every half second); the defaults ignore everything.

    ``name`` keys what :meth:`close` returns in the run's summary (default: the class's name);
    ``folder``, a folder the observer writes into while the run goes (the session watches its disk);
    ``failure``, set when an output could not be written (the session stops the run and reports it)."""

    name: str | None = None
    folder: Path | None = None
    failure: BaseException | None = None

    def warm_up(self) -> None:
        """Before the first packet (on the streaming thread): compile or load the kernels this observer
        will run, so none of it happens while commands are timed."""

    def started(self, t_us: int, initial: dict) -> None:
        """The first packet arrived at ``t_us``; ``initial`` maps lane -> its starting command."""

    def events(self, batch: np.ndarray) -> None:
        """A batch of events, shared by every lane of the source."""

    def packet(self, camera: str, packet) -> None:
        """A camera's exposure marker, frame, IMU or trigger batch (before the lanes see it)."""

    def command(self, lane: str, command, latency_us: float) -> None:
        """A lane's controller issued ``command``, handed to the source after ``latency_us``."""

    def prediction(self, lane: str, t_us: int, log_irradiance: float) -> None:
        """The lane's P-TEDI prediction ln P(t), sampled every few ms."""

    def frame(self, lane: str, frame: Frame, record: FrameRecord) -> None:
        """A frame of the lane's camera and what telemetry measured on it."""

    def note(self, entity: str, t_us: int, message: str, level: str = "INFO", data: dict | None = None) -> None:
        """A change during the run (tuning, controller switch); ``data`` for machine-readable logs."""

    def mark(self, text: str = "") -> str | None:
        """The user marked this moment (tuning's ``mark``): the observer's reply, or None if marks mean
        nothing to it (a flight recorder opens a clip around it)."""
        return None

    def close(self) -> dict | None:
        """The run is over: flush. May return statistics for the run summary."""
        return None


class Pipeline:
    """Runs lanes over a source on a streaming thread (or the caller's, with :meth:`run`).

    Parameters
    ----------
    source : a :class:`~necviz.drivers.source.Source`.
    lanes : the lanes (at most one driving lane per camera).
    telemetry : where per-frame metrics go (default: a :class:`Telemetry` keeping ``history`` frames per lane).
    history : frames of per-frame telemetry kept per lane by the default telemetry (``None``: all).
    observers : :class:`Observer` s (the Rerun sink, a recorder).
    speed : ``None`` as fast as possible; ``1.0`` real time; ``N`` N times real time.
    stop_after_s : end the run after this much sensor time (``None``: when the source ends).
    warm_up : compile or load every kernel before the first packet (:mod:`necviz.warmup`), so
        start-up never counts as command latency.
    """

    #: predictions go to observers at most this often (sensor time, µs)
    SAMPLE_PERIOD_US = 2_000

    def __init__(
        self,
        source,
        lanes: list[Lane],
        *,
        telemetry: Telemetry | None = None,
        history: int | None = None,
        observers=(),
        speed: float | None = None,
        stop_after_s: float | None = None,
        warm_up: bool = True,
    ):
        if not lanes:
            raise ParameterError("the pipeline needs at least one lane")
        if speed is not None and not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
            raise ParameterError(f"speed must be a positive number (1 = real time), got {speed!r}")
        names = [lane.name for lane in lanes]
        if len(set(names)) != len(names):
            raise ParameterError(f"lane names must be unique, got {names}")
        cameras = tuple(source.cameras)
        driven = set()
        for lane in lanes:
            if lane.camera is None:
                lane.camera = lane.name if lane.name in cameras else (cameras[0] if len(cameras) == 1 else None)
            if lane.camera not in cameras:
                raise ParameterError(
                    f"lane {lane.name!r} watches camera {lane.camera!r}, which the source does not "
                    f"have ({', '.join(cameras)})"
                )
            if lane.drives:
                if lane.camera in driven:
                    raise ParameterError(f"camera {lane.camera!r} is driven by more than one lane")
                driven.add(lane.camera)
            if lane.estimator is None:
                lane.passive = PeripheralEstimator(source.sensor)
        self.source = source
        self.lanes = {lane.name: lane for lane in lanes}
        self._watchers: dict[str, list[Lane]] = {c: [ln for ln in lanes if ln.camera == c] for c in cameras}
        self.telemetry = telemetry if telemetry is not None else Telemetry(names, history=history)
        missing = [n for n in names if n not in self.telemetry.lanes]
        if missing:
            raise ParameterError(f"the telemetry has no lane {missing[0]!r}")
        self.telemetry.attach(lanes, source)  # what the diagnosis of saturated frames needs to know
        limits = source.camera_info.limits
        #: each lane's reaction in sensor time (cause -> first exposure that used the command; :mod:`necviz.reaction`)
        self.reactions = {name: ReactionMeter(limits) for name in names}
        self.observers = list(observers)
        self.speed = speed
        self.sample_period_us = self.SAMPLE_PERIOD_US
        self.stop_after_us = None if stop_after_s is None else int(stop_after_s * 1e6)
        self.warm_up = bool(warm_up)
        self.error: BaseException | None = None
        self.wall_s = 0.0
        self._stop = threading.Event()
        self._done = threading.Event()
        self._pending: list = []  # (function, future): changes applied between packets
        self._finished = False
        self._thread: threading.Thread | None = None
        self.dvs = DvsControls(source, self.lanes)  # the camera's DVS biases, P-TEDI following them (issue 29)

    # -- what the run has seen so far (read from any thread) ------------------------------------
    @property
    def now_us(self) -> int | None:
        return self.telemetry.now_us

    @property
    def first_us(self) -> int | None:
        return self.telemetry.first_us

    @property
    def events(self) -> int:
        return self.telemetry.events

    @property
    def frames(self) -> int:
        return self.telemetry.frames

    # -- running ---------------------------------------------------------------------------------
    def start(self) -> Pipeline:
        self._thread = threading.Thread(target=self._run_guarded, name="necviz-stream", daemon=True)
        self._thread.start()
        return self

    def run(self) -> Pipeline:
        """Run on the calling thread (scripts, comparisons, benchmarks)."""
        self._run_guarded()
        return self

    def stop(self) -> None:
        self._stop.set()

    @property
    def running(self) -> bool:
        return self._thread is not None and not self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the streaming thread; True when it has ended.

        Waits on an event the thread sets last, not on ``Thread.join``: a join interrupted by
        Ctrl-C can mark a still-running thread as stopped (CPython 3.11).
        """
        if self._thread is None:
            return True
        return self._done.wait(timeout)

    # -- changes while running -------------------------------------------------------------------
    def submit(self, change) -> Future:
        """Run ``change(pipeline) -> (message, data)`` on the streaming thread between two packets.

        The future resolves with the message, or with the :class:`NecvizError` that refused it.
        Before the run starts, changes wait for its first packet; after it has ended they apply at once.
        """
        fut: Future = Future()
        self._pending.append((change, fut))
        if self._done.is_set():  # no streaming thread any more: apply now
            self._apply_changes()
        return fut

    def tune(self, key: str, value: float, lane: str | None = None) -> Future:
        """Set a tunable parameter (``key``) on one lane or on every lane that has it."""
        return self.submit(lambda p: p._tune(key, value, lane))

    def tune_dvs(self, key: str, value) -> Future:
        """Set a DVS control of the source's camera (``c_on``, ``bias.DiffBn``, ...: :mod:`necviz.dvs_controls`)."""
        # applied between packets, the source already streaming: P-TEDI follows where the change shows
        return self.submit(lambda p: p.dvs.set(key, value, p.telemetry.now_us, started=True))

    def drive(self, controller: str, lane: str | None = None) -> Future:
        """Let controller ``controller`` (a registered name) take over the lane's camera."""
        return self.submit(lambda p: p._drive(controller, lane))

    def _targets(self, lane: str | None) -> list[Lane]:
        if lane is None:
            return list(self.lanes.values())
        if lane not in self.lanes:
            raise ParameterError(f"no lane {lane!r}; lanes: {', '.join(self.lanes)}")
        return [self.lanes[lane]]

    def _tune(self, key: str, value, lane: str | None):
        targets = [ln for ln in self._targets(lane) if key in ln.tunables()]
        if not targets:
            raise ParameterError(f"no lane has a parameter {key!r}")
        limits = self.source.camera_info.limits  # what the camera itself can do, if it says
        if limits is not None and key in ("exposure_min", "exposure_max", "gain_max"):
            lo, hi = (1.0, limits.gain_max) if key == "gain_max" else (limits.exposure_min_us, limits.exposure_max_us)
            if not (isinstance(value, (int, float)) and lo <= value <= hi):
                raise ParameterError(f"{key} = {value:g} is outside what the camera accepts ({lo:g}..{hi:g})")
        if key in THRESHOLD_KEYS:
            v = check_number(key, value, 0.01, 2.0)
        else:  # check on every lane first, so a refusal changes nothing
            v = [ln.controller.check_param(key, value) for ln in targets][0]
        for ln in targets:
            if key in THRESHOLD_KEYS:
                est = _estimator(ln)
                p = est.params
                est.set_params(replace(p, c_on=v, c_off=v) if key == "c" else replace(p, **{key: v}))
            else:
                ln.controller.set_param(key, v)
        names = ", ".join(ln.name for ln in targets)
        return f"{key} = {v:g} on {names}", {"tuning": {"key": key, "value": v, "lanes": [ln.name for ln in targets]}}

    def _drive(self, controller: str, lane: str | None):
        if controller not in CONTROLLERS:
            raise ParameterError(f"unknown controller {controller!r}; available: {', '.join(sorted(CONTROLLERS))}")
        if lane is None:
            if len(self.lanes) != 1:
                raise ParameterError(
                    "drive: every controller drives its own camera here; name the lane (drive NAME LANE)"
                )
            ln = next(iter(self.lanes.values()))
        else:
            ln = self._targets(lane)[0]
        old = ln.controller
        est = _estimator(ln)  # a controller that owns an estimator adopts the lane's anchored one
        rate = self.source.camera_info.event_rate_max  # the source's bus ceiling (NEC's escape rule)
        ctx = ControllerContext(
            self.source.sensor, old.limits, old.exposure_us, old.gain, est.crf, est.params, est, rate
        )
        new = create_controller(controller, ctx)
        ln.switch(new)
        self.telemetry.attach([ln], self.source)
        self._note(S.path(ln.name, S.LOG), f"controller: {old.name} -> {controller}")
        return f"{controller} now drives {ln.camera} (was {old.name})", {
            "tuning": {"key": "drive", "value": controller, "lanes": [ln.name]}
        }

    def status(self) -> str:
        """The current settings of every lane, one line each."""
        lines = []
        for ln in self.lanes.values():
            c, p, lim = ln.controller, _estimator(ln).params, ln.controller.limits
            own = ", ".join(f"{k}={v:.4g}" for k, v in c.params().items())
            lines.append(
                f"{ln.name}: {c.name}{'' if ln.drives else ' (open loop)'}, c_on={p.c_on:g} c_off={p.c_off:g}, "
                f"exposure {lim.exposure_min_us:g}..{lim.exposure_max_us:g} µs, gain_max={lim.gain_max:g}"
                + (f", {own}" if own else "")
            )
        st = self.dvs.state
        if st is not None:  # the camera's DVS, once a control was set
            d = st.settings()
            lines.append(
                f"dvs: c_on={d.c_on:.4g} c_off={d.c_off:.4g} refractory={d.refractory_us:.4g} µs "
                f"bandwidth={d.bandwidth_hz:.4g} Hz, BA filter {st.ba_filter_steps * 250 or 'off'}"
                f"{' µs' if st.ba_filter_steps else ''}, refractory filter {st.refractory_filter_steps * 250 or 'off'}"
                f"{' µs' if st.refractory_filter_steps else ''}"
            )
        return "\n".join(lines)

    def _apply_changes(self) -> None:
        changes, self._pending = self._pending, []
        for change, fut in changes:
            try:
                msg, data = change(self)
            except NecvizError as e:
                self._note(S.TUNING, f"rejected: {e}", "WARN")
                fut.set_exception(e)
                continue
            self._note(S.TUNING, msg, "INFO", data)
            fut.set_result(msg)

    def _note(self, entity: str, message: str, level: str = "INFO", data: dict | None = None) -> None:
        if self._finished:  # the observers are closed: nothing more to log
            return
        t = self.telemetry.now_us or 0
        for o in self.observers:
            o.note(entity, t, message, level, data)

    # -- the streaming thread --------------------------------------------------------------------
    def _run_guarded(self) -> None:
        t0 = time.perf_counter()
        try:
            self._run()
        except BaseException as e:  # reported by finish(); the recording so far is flushed there
            self.error = e
        finally:
            self.wall_s = time.perf_counter() - t0
            for _change, fut in self._pending:  # submitted too late: say so
                fut.set_exception(ParameterError("the run ended before the change could be applied"))
            self._pending = []
            self._done.set()

    def _run(self) -> None:
        lanes = list(self.lanes.values())
        tel, observers, source = self.telemetry, self.observers, self.source
        lane_tel = {ln.name: tel[ln.name] for ln in lanes}
        if self.warm_up:  # before the first packet: compilation and cache loads never count as latency
            from necviz.warmup import warm_up_lanes

            warm_up_lanes(lanes, source.sensor)
            source.warm_up()
            for o in observers:
                o.warm_up()
        perf_ns = time.perf_counter_ns
        wall0 = time.perf_counter()
        next_sample = -(2**62)
        initial = {}
        for ln in lanes:  # the controller's starting setting goes to the camera first
            if ln.drives:
                initial[ln.name] = first = ln.controller.initial_command(0)
                source.set_exposure(ln.camera, first.exposure_us, first.gain)
        for cam, packet in source.packets():
            t_in = perf_ns()
            if self._pending:
                self._apply_changes()
            if self._stop.is_set():
                break
            t = packet_time_us(packet)
            if t is not None:
                if tel.first_us is None:
                    tel.first_us = t
                    wall0 = time.perf_counter()
                    for o in observers:
                        o.started(t, initial)
                if self.stop_after_us is not None and t - tel.first_us >= self.stop_after_us:
                    break
                if self.speed is not None:
                    ahead = (t - tel.first_us) / 1e6 / self.speed - (time.perf_counter() - wall0)
                    if ahead > 0:
                        if self._stop.wait(ahead):  # paced: a gap in the recording must not delay a stop
                            break
                        t_in = perf_ns()
                tel.now_us = t
            match packet:
                case EventBatch(events=batch):  # shared by every lane: the common case, kept short
                    if not len(batch):
                        continue
                    assert t is not None  # a batch with events has a time
                    tel.events += len(batch)
                    if self.dvs.pending:  # P-TEDI takes new thresholds where the bias change shows
                        self._dvs_follow(int(batch["t"][-1]))
                    for ln in lanes:  # control first: a lossless observer may make the thread wait
                        if ln.passive is not None:
                            ln.passive.update(batch)
                        cmd = ln.controller.feed_events(batch)
                        if cmd is not None:
                            self._command(ln, cmd, t_in, t)
                    for o in observers:
                        o.events(batch)
                    if observers and t >= next_sample:
                        next_sample = t + self.sample_period_us
                        self._sample(lanes, t)
                case Frame():
                    for o in observers:
                        o.packet(cam, packet)
                    watchers = self._watchers.get(cam)
                    if watchers:
                        tel.frames += 1
                    for ln in watchers or ():
                        self.reactions[ln.name].frame(packet.exposure_start_us, packet.exposure_us, packet.gain)
                        est = ln.passive.add_frame(packet) if ln.passive is not None else None
                        cmd = ln.controller.feed(packet)
                        if cmd is not None:
                            self._command(ln, cmd, t_in, t)
                        if est is None:
                            est = ln.controller.last_frame_estimate
                        rec = lane_tel[ln.name].frame(packet, est, _estimator(ln).min_valid_fraction)
                        for o in observers:
                            o.frame(ln.name, packet, rec)
                case ExposureMarker():
                    for o in observers:
                        o.packet(cam, packet)
                    for ln in self._watchers.get(cam, ()):
                        if packet.kind == "start":
                            lane_tel[ln.name].exposure_start(packet.t_us, ln.estimator)
                            self.reactions[ln.name].start(packet.t_us)
                        if ln.passive is not None:
                            ln.passive.feed(packet)
                        cmd = ln.controller.feed(packet)
                        if cmd is not None:
                            self._command(ln, cmd, t_in, t)
                case ImuBatch() | TriggerBatch():  # for observers only; no controller uses them
                    for o in observers:
                        o.packet(cam, packet)
                case _:  # e.g. a bare event array from a source written before EventBatch: never drop it silently
                    raise StreamError(
                        f"the source yielded a {type(packet).__name__}, which is not a stream packet "
                        "(events travel as EventBatch; see necviz.core.stream.Packet)"
                    )

    def _dvs_follow(self, last_event_us: int) -> None:
        t = self.dvs.follow_if_applied(last_event_us)
        if t is not None:
            now = ", ".join(f"{n}: c_on={c[0]:.4g} c_off={c[1]:.4g}" for n, c in self.dvs.followed.items())
            self._note(
                S.TUNING,
                f"P-TEDI thresholds follow the DVS biases from {t} µs ({now})",
                "INFO",
                {
                    "ptedi": {n: {"c_on": c[0], "c_off": c[1], "from_us": t} for n, c in self.dvs.followed.items()},
                    "ratio": self.dvs.ratio,
                    **({"dvs": self.dvs.replayed_dvs} if self.dvs.replayed_dvs else {}),  # a replay: the recorded DVS
                },
            )

    def _sample(self, lanes: list[Lane], t: int) -> None:
        """Every lane's P-TEDI prediction ln P(t), for the observers."""
        for ln in lanes:
            est = _estimator(ln)
            if not est.ready:
                continue
            lp = math.nan if ln.passive is not None else ln.controller.last_log_irradiance
            if not math.isfinite(lp):
                try:
                    lp = est.predict(t)
                except NecvizError:
                    continue
            if math.isfinite(lp):
                for o in self.observers:
                    o.prediction(ln.name, t, lp)

    def _command(self, ln: Lane, cmd, t_in: int, cause_us: int | None = None) -> None:
        if ln.drives:
            self.source.set_exposure(ln.camera, cmd.exposure_us, cmd.gain)
        if cause_us is not None:  # an open-loop lane's commands are counted, never matched to frames
            self.reactions[ln.name].command(cause_us, cmd.exposure_us, cmd.gain, applies=ln.drives)
        latency_us = (time.perf_counter_ns() - t_in) / 1e3
        self.telemetry[ln.name].command(latency_us, cmd)
        for o in self.observers:
            o.command(ln.name, cmd, latency_us)

    # -- end -------------------------------------------------------------------------------------
    def finish(self, close_source: bool = True) -> dict:
        """Close the source and the observers (flushing recordings); re-raise a streaming error.

        Returns the run's summary: :meth:`Telemetry.summary` plus ``wall_s`` and, per observer
        that reports any, its statistics under its ``name`` (the sink: ``"sink"``).
        """
        self.stop()
        errors = []
        closed = False
        if not self.wait(5.0) and close_source:
            try:  # the thread is blocked inside the source (a silent camera): closing it unblocks the read
                self.source.close()
            except BaseException as e:
                errors.append(e)
            closed = True
        self.wait()
        if close_source and not closed:
            try:
                self.source.close()
            except BaseException as e:  # keep flushing
                errors.append(e)
        extra = {}
        self._finished = True
        for o in self.observers:
            try:
                out = o.close()
                if out is not None:
                    extra[o.name or type(o).__name__] = out
            except BaseException as e:
                errors.append(e)
        err = self.error or (errors[0] if errors else None)
        self.error = None
        stats = {**self.telemetry.summary(), "wall_s": self.wall_s, **extra}
        for name, th in self.dvs.summary().items():  # the thresholds P-TEDI used at the end, beside its events
            stats["lanes"][name]["ptedi"] = th
        if self.dvs.history and self.dvs.state is not None:
            stats["dvs"] = {"changes": self.dvs.history, **self.dvs.state.settings().as_dict()}
        for name, lane in stats.get("lanes", {}).items():
            if name in self.reactions:
                lane["reaction"] = self.reactions[name].summary()
        if err is not None:
            raise err
        return stats


class RecorderObserver(Observer):
    """Keeps one camera's stream (shared events, its markers, frames, IMU, triggers), the commands of
    the lane that drives it, and every tuning change in a native recorder
    (:class:`~necviz.drivers.recordings.native.Recorder`)."""

    name = "recorder"

    def __init__(self, recorder, camera: str, lane: str | None = None):
        self.recorder = recorder
        self.camera = camera
        self.lane = lane or camera

    def events(self, batch):
        self.recorder.write(EventBatch(batch))

    def packet(self, camera, packet):
        if camera == self.camera:
            self.recorder.write(packet)

    def command(self, lane, command, latency_us):
        if lane == self.lane:
            from necviz.drivers.source import CommandRecord

            self.recorder.command(
                CommandRecord(int(command.issue_time_us), float(command.exposure_us), float(command.gain))
            )

    def note(self, entity, t_us, message, level="INFO", data=None):
        if data is not None:
            self.recorder.annotate(t_us, data)

    def close(self):
        self.recorder.close()
        return None


class DiskWatch(Observer):
    """The disks of a run's files (``files``: a session's ``--save`` file, native recording, clips' folder):
    every ``period_s`` of wall time while packets stream, whether one has less than half of
    :data:`~necviz.outputs.RECORDING_RESERVE` free plus what joining ``segments`` (a segmented ``--save``
    file, if any) will still write: its size (:func:`~necviz.outputs.low_space`). ``full``: ``(file, bytes free)``
    once one has, else None; the session's loop then stops the run while the files can still be completed.
    Checked after the lanes have acted on a packet (:meth:`events`, :meth:`frame`), beside the observers
    that write those files."""

    name = "disk"

    def __init__(self, files: list, segments=None, period_s: float = 0.5) -> None:
        self.files = files
        self.segments = segments
        self.period_s = period_s
        self.full: tuple[str, int] | None = None
        self._next = 0.0

    def _check(self) -> None:
        now = time.monotonic()
        if self.full is None and now >= self._next:
            self._next = now + self.period_s
            joining = self.segments.size() if self.segments is not None else 0  # the join copies the file
            self.full = low_space(self.files, extra=joining)

    def events(self, batch) -> None:
        self._check()

    def frame(self, lane, frame, record) -> None:
        self._check()


__all__ = ["DiskWatch", "Lane", "Observer", "Pipeline", "RecorderObserver", "THRESHOLD_KEYS", "packet_time_us"]
