"""The streaming pipeline: source -> P-TEDI -> controller -> command back to the source, and -> Rerun.

One *streaming thread* pulls packets from the source and, for every lane (a camera with its
controller), feeds the controller (NEC owns its P-TEDI estimator; the other lanes get a passive
P-TEDI estimator so every lane shows a prediction), sends any command straight back to the
source, and hands what it saw to the sink (:class:`~necviz.sink.RerunSink`) and the recorder
through calls that only append to memory. Commands therefore go out between frames, at the
rate event batches arrive, and never wait for visualisation.

Measured per command: the processing latency from the moment the packet that caused it left
the source to the moment the command was handed back to the source (``latency_us``; the
batch period of the source, ≤ 1 ms, comes on top in sensor time). Measured per stream: events,
frames, event rate.

Shutdown: source end, :meth:`Pipeline.stop` (Ctrl-C in the CLI) or a source error all end the
streaming thread; :meth:`Pipeline.finish` then closes the source and flushes the recorder and
the sink, and re-raises the error if there was one — so what was seen before a fault is kept.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from . import schema as S
from .core.control import Controller, NECController
from .core.errors import NecvizError, ParameterError
from .core.event_model import TediParams
from .core.frames import ExposureMarker, Frame
from .core.imu import ImuBatch, TriggerBatch
from .core.metrics import over_exposed_rate, under_exposed_rate
from .core.ptedi import PeripheralEstimator
from .drivers.source import CommandRecord


def packet_time_us(packet) -> int | None:
    """Sensor time a packet completes at (events: last event; frame: exposure end)."""
    if isinstance(packet, np.ndarray):
        return int(packet["t"][-1]) if len(packet) else None
    if isinstance(packet, ExposureMarker):
        return int(packet.t_us)
    if isinstance(packet, Frame):
        return int(packet.exposure_end_us)
    if isinstance(packet, ImuBatch):
        return int(packet.samples["t"][-1]) if len(packet) else None
    if isinstance(packet, TriggerBatch):
        return int(packet.triggers["t"][-1]) if len(packet) else None
    return None


@dataclass
class Lane:
    """One camera and the controller that drives it (or would, in open loop).

    ``estimator`` is NEC's own P-TEDI estimator, or a passive one fed beside any other
    controller. ``drives``: commands go back to the source (False: shown only).
    """

    name: str
    controller: Controller
    estimator: PeripheralEstimator
    drives: bool = True
    passive_estimator: bool = False
    # run state
    next_prediction_us: int = -(2**62)
    predicted_at_start: dict = field(default_factory=dict)
    latencies_ns: list = field(default_factory=list)
    commands: int = 0
    frames: int = 0
    saturated_frames: int = 0
    frames_detail: list = field(default_factory=list)

    @classmethod
    def build(cls, name: str, controller: Controller, sensor, drives: bool = True, tedi=None, crf=None) -> "Lane":
        """NEC brings its estimator; any other controller gets a passive one on ``sensor``."""
        if isinstance(controller, NECController):
            return cls(name, controller, controller.estimator, drives)
        return cls(name, controller, PeripheralEstimator(sensor, tedi or TediParams(), crf), drives, True)


def percentile_us(latencies_ns: list, q: float) -> float:
    return float(np.percentile(np.asarray(latencies_ns, np.float64), q) / 1e3) if latencies_ns else math.nan


class Pipeline:
    """Runs lanes over a source on a streaming thread.

    Parameters
    ----------
    source : a :class:`~necviz.drivers.source.Source` (one lane) or a
        :class:`~necviz.drivers.sim.camera.SimRig` (one lane per camera, named like its cameras).
    lanes : the lanes, by name.
    sink : a :class:`~necviz.sink.RerunSink` or ``None``.
    recorder : an object with ``write(packet)``, ``command(CommandRecord)``,
        ``annotate(t_us, dict)``, ``close()`` (the native recorder), or ``None``.
    record_lane : the lane whose camera the recorder keeps (default: the first).
    speed : ``None`` as fast as possible; ``1.0`` real time; ``N`` N times real time.
    prediction_period_us : the predicted irradiance is logged at most this often per lane.
    stop_after_s : end the run after this much sensor time (``None``: when the source ends).
    """

    def __init__(self, source, lanes: list[Lane], sink=None, recorder=None, record_lane: str | None = None,
                 speed: float | None = None, prediction_period_us: int = 2_000, stop_after_s: float | None = None):
        if not lanes:
            raise ParameterError("the pipeline needs at least one lane")
        if speed is not None and not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
            raise ParameterError(f"speed must be a positive number (1 = real time), got {speed!r}")
        self.source = source
        self.multi = hasattr(source, "packets") and hasattr(source, "cams")
        self.lanes = {lane.name: lane for lane in lanes}
        if len(self.lanes) != len(lanes):
            raise ParameterError(f"lane names must be unique, got {[lane.name for lane in lanes]}")
        if not self.multi and len(self.lanes) != 1:
            raise ParameterError("a single-camera source takes exactly one lane")
        self._only = lanes[0]
        self.sink = sink
        self.recorder = recorder
        self.record_lane = record_lane or lanes[0].name
        self.speed = speed
        self.prediction_period_us = int(prediction_period_us)
        self.stop_after_us = None if stop_after_s is None else int(stop_after_s * 1e6)
        self.events = 0
        self.frames = 0
        self.now_us: int | None = None
        self.first_us: int | None = None
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._pending: list = []  # live-tuning changes, applied between packets
        self._thread: threading.Thread | None = None
        self.wall_s = 0.0

    # -- control ------------------------------------------------------------------------------
    def submit(self, change) -> None:
        """Queue ``change(pipeline) -> str`` to run on the streaming thread between packets."""
        self._pending.append(change)

    def stop(self) -> None:
        self._stop.set()

    @property
    def running(self) -> bool:
        return self._thread is not None and not self._done.is_set()

    def start(self) -> "Pipeline":
        self._thread = threading.Thread(target=self._run_guarded, name="necviz-stream", daemon=True)
        self._thread.start()
        return self

    def run(self) -> "Pipeline":
        """Run on the calling thread (tests, benchmarks)."""
        self._run_guarded()
        return self

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the streaming thread; True when it has ended.

        Waits on an event the thread sets last, not on ``Thread.join``: a join interrupted by
        Ctrl-C can mark a still-running thread as stopped (CPython 3.11).
        """
        if self._thread is None:
            return True
        return self._done.wait(timeout)

    # -- the streaming thread -----------------------------------------------------------------
    def _packets(self):
        if self.multi:
            yield from self.source.packets()
        else:
            name = self._only.name
            for packet in self.source:
                yield (None if isinstance(packet, np.ndarray) else name), packet

    def _apply(self, lane: Lane, cmd) -> None:
        if not lane.drives:
            return
        if self.multi:
            self.source.set_exposure(lane.name, cmd.exposure_us, cmd.gain, issue_time_us=cmd.issue_time_us)
        else:
            self.source.set_exposure(cmd.exposure_us, cmd.gain, issue_time_us=cmd.issue_time_us)

    def _run_guarded(self) -> None:
        t0 = time.perf_counter()
        try:
            self._run()
        except BaseException as e:  # reported by finish(); the recording so far is flushed there
            self.error = e
        finally:
            self.wall_s = time.perf_counter() - t0
            self._done.set()

    def _run(self) -> None:
        lanes = list(self.lanes.values())
        sink, rec = self.sink, self.recorder
        wall0 = time.perf_counter()
        perf_ns = time.perf_counter_ns
        initial = {}
        for lane in lanes:  # the controller's starting setting goes to the camera first
            if lane.drives:
                initial[lane.name] = cmd = lane.controller.initial_command(0)
                self._apply(lane, cmd)
        for cam, packet in self._packets():
            t_in = perf_ns()
            if self._pending:
                self._apply_changes()
            if self._stop.is_set():
                break
            if cam is None and type(packet) is np.ndarray:  # the common case, kept short
                if not len(packet):
                    continue
                t = int(packet["t"][-1])
            else:
                t = packet_time_us(packet)
            if t is not None:
                if self.first_us is None:
                    self.first_us = t
                    wall0 = time.perf_counter()
                    if sink is not None:  # the commanded series start with the setting the run began with
                        for name, cmd in initial.items():
                            sink.scalar(name, S.EXPOSURE_COMMANDED, t, cmd.exposure_us)
                            sink.scalar(name, S.GAIN_COMMANDED, t, cmd.gain)
                if self.stop_after_us is not None and t - self.first_us >= self.stop_after_us:
                    break
                if self.speed is not None:
                    ahead = (t - self.first_us) / 1e6 / self.speed - (time.perf_counter() - wall0)
                    if ahead > 0:
                        if self._stop.wait(ahead):  # paced: a gap in the recording must not delay a stop
                            break
                        t_in = perf_ns()
                self.now_us = t
            if cam is None:  # events, shared by every lane
                if not isinstance(packet, np.ndarray):  # pragma: no cover - sources yield (None, events) only
                    continue
                self.events += len(packet)
                if sink is not None:
                    sink.events(packet)
                if rec is not None:
                    rec.write(packet)
                for lane in lanes:  # the hot path (every event batch), inlined
                    if lane.passive_estimator:
                        lane.estimator.update(packet)
                    cmd = lane.controller.feed(packet)
                    if cmd is not None:
                        self._command(lane, cmd, t_in)
                    if sink is not None and t >= lane.next_prediction_us:
                        self._log_prediction(lane, t)
            else:
                lane = self.lanes.get(cam)
                if lane is None:
                    continue
                if rec is not None and cam == self.record_lane:
                    rec.write(packet)
                if isinstance(packet, Frame):
                    self.frames += 1
                    self._frame(lane, packet, t_in)
                elif isinstance(packet, ExposureMarker):
                    if packet.kind == "start" and lane.estimator.ready:
                        try:
                            lane.predicted_at_start[packet.t_us] = lane.estimator.predict(packet.t_us)
                        except NecvizError:
                            pass
                    self._feed(lane, packet, t_in, t)
                else:  # IMU, triggers: recorded, not used by controllers
                    pass

    def _feed(self, lane: Lane, packet, t_in: int, t: int | None) -> None:
        """An exposure marker (frames: :meth:`_frame`; event batches are handled inline in :meth:`_run`)."""
        if lane.passive_estimator:
            lane.estimator.feed(packet)
        cmd = lane.controller.feed(packet)
        if cmd is not None:
            self._command(lane, cmd, t_in)

    def _log_prediction(self, lane: Lane, t: int) -> None:
        """P-TEDI's ln P(t) for the lane, at most every ``prediction_period_us``."""
        if not lane.estimator.ready:
            return
        lp = math.nan if lane.passive_estimator else getattr(lane.controller, "last_log_irradiance", math.nan)
        if not math.isfinite(lp):
            try:
                lp = lane.estimator.predict(t)
            except NecvizError:
                return
        if math.isfinite(lp):
            self.sink.scalar(lane.name, S.IRRADIANCE_PREDICTED, t, lp)
            lane.next_prediction_us = t + self.prediction_period_us

    def _command(self, lane: Lane, cmd, t_in: int) -> None:
        self._apply(lane, cmd)
        lat = time.perf_counter_ns() - t_in
        lane.latencies_ns.append(lat)
        lane.commands += 1
        if self.recorder is not None and lane.name == self.record_lane:
            self.recorder.command(CommandRecord(int(cmd.issue_time_us), float(cmd.exposure_us), float(cmd.gain)))
        sink = self.sink
        if sink is not None:
            t = int(cmd.issue_time_us)
            sink.scalar(lane.name, S.EXPOSURE_COMMANDED, t, cmd.exposure_us)
            sink.scalar(lane.name, S.GAIN_COMMANDED, t, cmd.gain)
            sink.scalar(lane.name, S.LATENCY, t, lat / 1e3)

    def _frame(self, lane: Lane, frame: Frame, t_in: int) -> None:
        fe = lane.estimator.feed(frame) if lane.passive_estimator else None
        cmd = lane.controller.feed(frame)
        if cmd is not None:
            self._command(lane, cmd, t_in)
        if fe is None:
            fe = getattr(lane.controller, "last_frame_estimate", None)
        over, under = over_exposed_rate(frame.image), under_exposed_rate(frame.image)
        lane.frames += 1
        saturated = max(over, under) > 0.5
        lane.saturated_frames += saturated
        detail = {"sequence": int(frame.sequence), "exposure_start_us": int(frame.exposure_start_us),
                  "exposure_us": int(frame.exposure_us), "gain": float(frame.gain),
                  "over_exposed_rate": float(over), "under_exposed_rate": float(under), "saturated": bool(saturated),
                  "measured_log_irradiance": None, "predicted_log_irradiance": None, "prediction_error": None}
        pred_s = lane.predicted_at_start.pop(frame.exposure_start_us, None)
        for k in [k for k in lane.predicted_at_start if k < frame.exposure_start_us]:
            del lane.predicted_at_start[k]
        if fe is not None:
            measured = float(fe.log_mean_irradiance[0]) if fe.log_mean_irradiance.size == 1 else float(
                np.nanmean(fe.log_mean_irradiance))
            usable = bool(np.all(fe.valid_fraction >= lane.estimator.min_valid_fraction))
            if math.isfinite(measured) and usable:
                detail["measured_log_irradiance"] = measured
                if pred_s is not None and math.isfinite(pred_s):
                    predicted = pred_s + float(np.mean(fe.log_e))  # ln Pbar = ln P(s) + ln E_p(s)
                    detail["predicted_log_irradiance"] = predicted
                    detail["prediction_error"] = predicted - measured
        lane.frames_detail.append(detail)
        sink = self.sink
        if sink is not None:
            t, seq = int(frame.exposure_start_us), int(frame.sequence)
            sink.frame(lane.name, frame, over, under)
            sink.scalar(lane.name, S.EXPOSURE_APPLIED, t, frame.exposure_us, seq)
            sink.scalar(lane.name, S.GAIN_APPLIED, t, frame.gain, seq)
            sink.scalar(lane.name, S.OVER_EXPOSED, t, over, seq)
            sink.scalar(lane.name, S.UNDER_EXPOSED, t, under, seq)
            if detail["measured_log_irradiance"] is not None:
                sink.scalar(lane.name, S.IRRADIANCE_FRAME, t, detail["measured_log_irradiance"], seq)
            if detail["prediction_error"] is not None:
                sink.scalar(lane.name, S.PREDICTION_ERROR, t, detail["prediction_error"], seq)

    def _apply_changes(self) -> None:
        changes, self._pending = self._pending, []
        t = self.now_us or 0
        for change in changes:
            try:
                msg, data = change(self)
                level = "INFO"
            except NecvizError as e:
                msg, data, level = f"rejected: {e}", None, "WARN"
            if self.sink is not None:
                self.sink.text(S.TUNING, t, msg, level)
            if self.recorder is not None and data is not None:
                self.recorder.annotate(t, data)
            if hasattr(change, "reply"):
                change.reply(msg)

    # -- end ----------------------------------------------------------------------------------
    def finish(self, close_source: bool = True) -> dict:
        """Close the source, flush the recorder and sink; re-raise a streaming error; return stats."""
        self.stop()
        errors = []
        closed = False
        if not self.wait(5.0) and close_source and hasattr(self.source, "close"):
            try:  # the thread is blocked inside the source (a silent camera): closing it unblocks the read
                self.source.close()
            except BaseException as e:
                errors.append(e)
            closed = True
        self.wait()
        if close_source and not closed and hasattr(self.source, "close"):
            try:
                self.source.close()
            except BaseException as e:  # keep flushing
                errors.append(e)
        sink_stats = None
        for closer in (self.recorder, self.sink):
            if closer is None:
                continue
            try:
                out = closer.close()
                if closer is self.sink:
                    sink_stats = out
            except BaseException as e:
                errors.append(e)
        err = self.error or (errors[0] if errors else None)
        self.error = None
        stats = self.stats(sink_stats)
        if err is not None:
            raise err
        return stats

    def stats(self, sink_stats: dict | None = None) -> dict:
        span_s = ((self.now_us or 0) - (self.first_us or 0)) / 1e6
        out = {"events": self.events, "frames": self.frames, "duration_s": span_s, "wall_s": self.wall_s,
               "event_rate_mev_s": self.events / span_s / 1e6 if span_s > 0 else 0.0, "lanes": {}}
        for lane in self.lanes.values():
            out["lanes"][lane.name] = {
                "commands": lane.commands, "frames": lane.frames, "saturated_frames_50": lane.saturated_frames,
                "latency_p50_us": percentile_us(lane.latencies_ns, 50),
                "latency_p99_us": percentile_us(lane.latencies_ns, 99),
            }
        if sink_stats is not None:
            out["sink"] = sink_stats
        return out


__all__ = ["Lane", "Pipeline", "packet_time_us", "percentile_us"]
