"""The flight recorder: keep the last seconds of a run in bounded memory, write a clip around every failure.

A live session lasts an hour; what matters are the ten seconds around each saturated frame. A
:class:`FlightRecorder` is a pipeline :class:`~necviz.pipeline.Observer` that keeps everything the
observers are told — event batches, markers, frames (with their telemetry), IMU and triggers,
commands, predictions, tuning and other notes — in a ring buffer covering the last ``before_s``
seconds of sensor time. When a lane's frame is saturated (:class:`~necviz.dashboard.telemetry.FrameRecord`,
more than half its pixels clipped) or the user types ``mark`` at the tuning prompt, a clip opens: the
ring's content plus everything until ``after_s`` after the failure. A failure while a clip is open
extends it (overlapping clips merge). A closed clip is handed to a writer thread, which writes into
``folder``:

* ``<time>-<cause>.necrec`` — the native recording of the failing lane's camera (events, frames,
  IMU, triggers, that lane's commands, every note), with the failure in its header
  (``clip_failure_us``, ``clip_cause``): ``necviz replay`` opens it looping over the failure;
* ``<time>-<cause>.rrd`` — what the dashboard showed over the clip, every lane, in the session's layout.

``<time>`` is the local wall-clock time of the failure and its sensor time from the start of the run
(``20250101-120301-t812.345s``); ``<cause>`` the diagnosis of the first saturated frame
(:mod:`necviz.core.diagnosis`: ``command_latency``, ``limit_reached`` ...), ``saturated`` when none was
named, or ``mark``.

Memory stays bounded whatever the event rate, at three budgets (:attr:`ClipOptions.memory_mb`, events
and frame pixels counted): the ring holds at most one (older entries are dropped first, and the drops are counted
and reported: a clip then covers less than ``before_s``); a clip being collected at most one (it is cut
there, and a new one starts at the next failure); the clips waiting for the writer at most one
together (and at most :data:`MAX_PENDING`; a clip that does not fit is dropped and counted). At the
DAVIS346's full 12 Mev/s, 5 s of events are 780 MB: size ``--clip-memory`` for the rate you expect. Simulated frames' ground truth is not kept. The streaming
thread only appends to memory; files are written by the writer thread. A run without a failure or a
mark writes nothing.
"""

from __future__ import annotations

import dataclasses
import queue
import re
import threading
import time
from collections import deque
from pathlib import Path

from necviz.core.errors import ParameterError
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch
from necviz.options import ClipOptions
from necviz.pipeline import Observer, RecorderObserver, packet_time_us

#: Clips waiting for the writer beyond the one being written; more are dropped (and counted).
MAX_PENDING = 2
#: Bytes counted for an entry that holds no array (a command, a prediction, a note).
SMALL = 160
#: Extra sensor time the ring keeps, so a clip still holds ``before_s`` before a saturated frame's
#: exposure *start* when the frame is only known at its end (exposures up to this long).
SLACK_US = 200_000
#: Seconds around the failure the viewer of a clip loops over.
FOCUS_S = 1.0


def cause_slug(cause: str) -> str:
    """A diagnosed cause as a file-name part (``command_latency``); ``saturated`` when none was named."""
    slug = re.sub(r"[^A-Za-z0-9_-]+", "-", str(cause or "").strip()).strip("-")
    return slug or "saturated"


@dataclasses.dataclass
class _Clip:
    items: list
    failure_us: int
    end_us: int
    cause: str
    lane: str | None
    wall: float
    failures: int = 1
    marks: int = 0
    nbytes: int = 0
    cut: bool = False


def _from(ring, lo: int) -> list:
    """The ring's entries from ``lo`` on, without the end marker, frame and frame record of an exposure
    that started before ``lo`` (a clip never begins inside an exposure)."""
    out, started = [], set()
    for it in ring:
        if it[0] < lo:
            continue
        method, args = it[2], it[3]
        if method == "packet" and isinstance(args[1], ExposureMarker):
            if args[1].kind == "start":
                started.add(args[0])
            elif args[0] not in started:
                continue
        elif method == "packet" and isinstance(args[1], Frame) and args[1].exposure_start_us < lo:
            continue
        elif method == "frame" and args[1].exposure_start_us < lo:
            continue
        out.append(it)
    return out


class FlightRecorder(Observer):
    """Keeps the last ``before_s`` seconds in a byte-bounded ring; writes a clip around every failure.

    Parameters
    ----------
    options : ClipOptions
        Where clips go (``folder``: must exist and be writable, :meth:`ClipOptions.check`, which the
        command runs beforehand), the seconds kept before a failure and recorded after it
        (``before_s``, ``after_s``) and the ring's memory budget (``memory_mb``: events and frame
        pixels). Its ranges are checked when it is built.
    sensor : SensorGeometry
        The source's sensor.
    lanes : dict
        ``{lane name: camera}`` of the session, in display order.
    drivers : dict
        ``{camera: the lane that drives it}`` (whose commands a clip's native recording keeps).
    layout : str
        The dashboard layout the clip's ``.rrd`` opens in (``live``, ``compare`` ...).
    properties : dict, optional
        The session's properties (stored in every clip).
    event_window_ms : float
        The event image window of the clip's dashboard.
    out : optional
        Where a line per written clip is printed (``None``: nowhere).

    Raises
    ------
    ParameterError
        ``options`` that is not a :class:`ClipOptions`.
    """

    name = "flight_recorder"

    def __init__(
        self,
        options: ClipOptions,
        *,
        sensor,
        lanes: dict,
        drivers: dict,
        layout: str,
        properties: dict | None = None,
        event_window_ms: float = 33.3,
        out=None,
    ):
        if not isinstance(options, ClipOptions):
            raise ParameterError(f"FlightRecorder takes ClipOptions, got {type(options).__name__}")
        self.folder = Path(options.folder)
        self.sensor = sensor
        self.lanes = dict(lanes)
        self.drivers = dict(drivers)
        self.layout = layout
        self.before_us = int(options.before_s * 1e6)
        self.after_us = int(options.after_s * 1e6)
        self.budget = int(options.memory_mb * 2**20)
        self.properties = dict(properties or {})
        self.event_window_us = int(event_window_ms * 1000)
        self.out = out
        self._ring: deque = deque()  # (t_us, nbytes, method, args)
        self._ring_bytes = 0
        self._clip: _Clip | None = None
        self._covered_us: int | None = None  # sensor time up to which clips have been taken
        self._now: int | None = None
        self._origin: int | None = None
        self._initial: dict = {}
        self._frame_ids: tuple[int, Frame] | None = None  # the last frame, without its ground truth
        self._marks: list[str] = []
        self.stats = {
            "clips_written": 0,
            "clips_dropped": 0,
            "clips_cut": 0,
            "failures": 0,
            "marks": 0,
            "dropped_events": 0,
            "dropped_bytes": 0,
            "peak_bytes": 0,
            "write_errors": 0,
            "files": [],
        }
        self._queue: queue.Queue = queue.Queue()
        self._pending = 0
        self._queued_bytes = 0  # bytes of the clips handed to the writer and not yet written
        self._lock = threading.Lock()
        self._writer = threading.Thread(target=self._write_loop, name="necviz-flight-recorder", daemon=True)
        self._writer.start()

    # -- the ring ---------------------------------------------------------------------------------
    def _add(self, t_us: int | None, nbytes: int, method: str, args: tuple) -> None:
        if t_us is not None and (self._now is None or t_us > self._now):
            self._now = int(t_us)
        now = self._now if self._now is not None else 0
        item = (now if t_us is None else int(t_us), nbytes, method, args)
        ring = self._ring
        ring.append(item)
        self._ring_bytes += nbytes
        horizon = now - self.before_us - SLACK_US
        while ring and ring[0][0] < horizon:
            self._ring_bytes -= ring.popleft()[1]
        while self._ring_bytes > self.budget and len(ring) > 1:  # over budget: drop the oldest, and say so
            t, n, m, a = ring.popleft()
            self._ring_bytes -= n
            self.stats["dropped_bytes"] += n
            if m == "events":
                self.stats["dropped_events"] += len(a[0])
        clip = self._clip
        if clip is not None:
            clip.items.append(item)
            clip.nbytes += nbytes
            if clip.nbytes > self.budget:  # a failure that lasts (or a budget smaller than the window): cut here
                clip.cut = True
                self.stats["clips_cut"] += 1
                self._close_clip()
            elif now > clip.end_us:
                self._close_clip()
        held = self._ring_bytes + (self._clip.nbytes if self._clip is not None else 0) + self._queued_bytes
        if held > self.stats["peak_bytes"]:
            self.stats["peak_bytes"] = held

    def _open(self, failure_us: int, cause: str, lane: str | None, mark: bool = False) -> None:
        clip = self._clip
        if clip is not None:  # overlapping: one clip
            clip.end_us = max(clip.end_us, failure_us + self.after_us)
            clip.failures += 0 if mark else 1
            clip.marks += 1 if mark else 0
            return
        lo = failure_us - self.before_us
        if self._covered_us is not None:  # never twice in two clips: start after the last one
            lo = max(lo, self._covered_us + 1)
        items = _from(self._ring, lo)
        self._clip = _Clip(
            items,
            failure_us,
            failure_us + self.after_us,
            cause,
            lane,
            time.time(),
            failures=0 if mark else 1,
            marks=1 if mark else 0,
            nbytes=sum(it[1] for it in items),
        )

    def _close_clip(self) -> None:
        clip, self._clip = self._clip, None
        if clip is None:
            return
        if clip.items:
            self._covered_us = clip.items[-1][0]
        with self._lock:
            # the clips waiting for the writer hold at most one budget (a lone clip is always taken)
            if self._pending > MAX_PENDING or (self._pending and self._queued_bytes + clip.nbytes > self.budget):
                self.stats["clips_dropped"] += 1
                return
            self._pending += 1
            self._queued_bytes += clip.nbytes
        self._queue.put(clip)

    def mark(self, text: str = "") -> str:
        """Open (or extend) a clip now, as for a failure (``mark`` at the tuning prompt; streaming thread)."""
        now = self._now if self._now is not None else 0
        self.stats["marks"] += 1
        self._open(now, "mark", None, mark=True)
        return f"clip marked at {self._t(now):.3f} s; it is written {self.after_us / 1e6:g} s from now to {self.folder}"

    def _t(self, t_us: int) -> float:
        return (t_us - (self._origin or 0)) / 1e6

    # -- observer ---------------------------------------------------------------------------------
    def started(self, t_us, initial):
        self._origin = int(t_us)
        self._initial = dict(initial)
        self._now = int(t_us)

    def events(self, batch):
        if len(batch):
            self._add(int(batch["t"][-1]), batch.nbytes, "events", (batch,))

    def _bare(self, frame: Frame) -> Frame:
        """The frame without its ground truth (simulated frames carry per-pixel truth: not kept)."""
        if getattr(frame, "truth", None) is None:
            return frame
        last = self._frame_ids
        if last is not None and last[0] == id(frame):
            return last[1]
        bare = dataclasses.replace(frame, truth=None)
        self._frame_ids = (id(frame), bare)
        return bare

    def packet(self, camera, packet):
        match packet:
            case Frame():
                packet = self._bare(packet)
                n = packet.image.nbytes + SMALL
            case ImuBatch():
                n = SMALL + packet.samples.nbytes
            case TriggerBatch():
                n = SMALL + packet.triggers.nbytes
            case _:
                n = SMALL
        self._add(packet_time_us(packet), n, "packet", (camera, packet))

    def command(self, lane, command, latency_us):
        self._add(None, SMALL, "command", (lane, command, latency_us))

    def prediction(self, lane, t_us, log_irradiance):
        self._add(int(t_us), SMALL, "prediction", (lane, t_us, log_irradiance))

    def frame(self, lane, frame, record):
        frame = self._bare(frame)
        t = int(frame.exposure_end_us)
        self._add(t, SMALL, "frame", (lane, frame, record))  # pixels counted with the camera's packet
        if record.saturated:
            self.stats["failures"] += 1
            self._open(int(frame.exposure_start_us), record.saturation_cause, lane)

    def note(self, entity, t_us, message, level="INFO", data=None):
        self._add(int(t_us), SMALL, "note", (entity, t_us, message, level, data))

    def close(self):
        """Write the clip still being collected (cut short by the end of the run) and wait for the writer."""
        if self._clip is not None:
            self._close_clip()
        self._queue.put(None)
        self._writer.join()
        self._ring.clear()
        self._ring_bytes = 0
        return dict(self.stats, buffer_bytes=self.budget)

    # -- the writer thread ------------------------------------------------------------------------
    def _write_loop(self) -> None:
        while True:
            clip = self._queue.get()
            if clip is None:
                return
            try:
                paths = self.write_clip(clip)
                self.stats["clips_written"] += 1
                self.stats["files"] += [str(p) for p in paths]
                if self.out is not None:
                    print(
                        f"\n  clip: {paths[0]} ({clip.cause or 'saturated'}, {clip.failures} failures)", file=self.out
                    )
            except Exception as e:  # noqa: BLE001 - a full disk must not end the session; counted and said
                self.stats["write_errors"] += 1
                if self.out is not None:
                    print(f"\n  clip: could not be written ({type(e).__name__}: {e})", file=self.out)
            finally:
                with self._lock:
                    self._pending -= 1
                    self._queued_bytes -= clip.nbytes
                clip.items.clear()

    def clip_name(self, clip: _Clip) -> str:
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(clip.wall))
        base = f"{stamp}-t{self._t(clip.failure_us):.3f}s-{cause_slug(clip.cause)}"
        name, k = base, 2
        while (self.folder / f"{name}.necrec").exists() or (self.folder / f"{name}.rrd").exists():
            name, k = f"{base}-{k}", k + 1
        return name

    def write_clip(self, clip: _Clip) -> list[Path]:
        """Write ``clip`` as ``<name>.necrec`` and ``<name>.rrd``; returns both paths."""
        from necviz.drivers.recordings.native import Recorder
        from necviz.writers import written

        name = self.clip_name(clip)
        lane = clip.lane or next(iter(self.lanes))
        camera = self.lanes.get(lane, lane)
        driver = self.drivers.get(camera, lane)
        start = clip.items[0][0] if clip.items else clip.failure_us
        end = clip.items[-1][0] if clip.items else clip.failure_us
        props = {
            **{k: str(v) for k, v in self.properties.items()},
            "clip_cause": clip.cause or "saturated",
            "clip_failure_us": clip.failure_us,
            "clip_failure_s": round(self._t(clip.failure_us), 6),
            "clip_lane": lane,
            "clip_camera": camera,
            "clip_failures": clip.failures,
            "clip_marks": clip.marks,
            "clip_start_us": start,
            "clip_end_us": end,
            "clip_cut": clip.cut,
            "clip_dropped_events_so_far": self.stats["dropped_events"],
        }
        necrec = self.folder / f"{name}.necrec"
        rrd = self.folder / f"{name}.rrd"
        with written(necrec) as tmp:
            rec = Recorder(tmp, sensor=self.sensor, properties=props)
            native = RecorderObserver(rec, camera, driver)
            try:
                self._replay(clip, native)
            finally:
                rec.close()
        with written(rrd) as tmp:
            self._write_rrd(clip, tmp, props, start)
        return [necrec, rrd]

    def _replay(self, clip: _Clip, observer) -> None:
        for _, _, method, args in clip.items:
            getattr(observer, method)(*args)

    def _write_rrd(self, clip: _Clip, path: Path, props: dict, start_us: int) -> None:
        import rerun as rr

        from necviz.dashboard.sink import RerunSink, SinkOptions
        from necviz.dashboard.viewer import file_batching
        from necviz.layouts import make_blueprint, style_series

        names = list(self.lanes)
        origin = self._origin if self._origin is not None else start_us
        bp = focus_blueprint(
            make_blueprint(self.layout, names, self.sensor.width, self.sensor.height),
            self._t(clip.failure_us) - FOCUS_S,
            self._t(clip.failure_us) + FOCUS_S,
        )
        rec = rr.RecordingStream("necviz", batcher_config=file_batching())
        rec.set_sinks(rr.FileSink(str(path)), default_blueprint=bp)
        try:
            rec.send_recording_name(f"necviz clip: {clip.cause or 'saturated'} at {self._t(clip.failure_us):.3f} s")
            rec.send_property("run", rr.AnyValues(**{k: str(v) for k, v in props.items()}, layout=self.layout))
            style_series(rec, names)
            options = SinkOptions(event_window_us=self.event_window_us, origin_us=origin, lossless=True)
            sink = RerunSink(rec, names, self.sensor.height, self.sensor.width, options)
            sink.started(start_us, self._initial)
            self._replay(clip, sink)
            sink.close()
        finally:
            rec.flush()
            rr.disconnect(rec)


def focus_blueprint(blueprint, start_s: float, end_s: float):
    """``blueprint`` with its time panel selecting ``[start_s, end_s]`` of sensor time and looping over it
    (how a clip's ``.rrd`` and ``necviz replay CLIP`` open at the failure)."""
    import rerun.blueprint as rrb
    from rerun.encodings import AbsoluteTimeRange, TimeInt

    from necviz.dashboard import schema as S

    blueprint.time_panel = rrb.TimePanel(
        state="expanded",
        timeline=S.TIME,
        time_selection=AbsoluteTimeRange(TimeInt(seconds=max(0.0, start_s)), TimeInt(seconds=max(0.0, end_s))),
        loop_mode="selection",
        play_state="playing",
    )
    return blueprint


def clip_observer(options):
    """A session observer factory (:class:`necviz.dashboard.session.Session` ``observers``) for
    :class:`~necviz.options.ClipOptions`: a :class:`FlightRecorder` on the session's lanes and layout."""

    def make(session, layout: str, out):
        lanes = {ln.name: ln.camera or ln.name for ln in session.lanes}
        drivers = {}
        for ln in session.lanes:
            if ln.drives:
                drivers.setdefault(ln.camera or ln.name, ln.name)
        return FlightRecorder(
            options,
            sensor=session.source.sensor,
            lanes=lanes,
            drivers=drivers,
            layout=layout,
            properties=session.properties,
            event_window_ms=session.show.event_window_ms,
            out=out,
        )

    return make


__all__ = ["FlightRecorder", "MAX_PENDING", "cause_slug", "clip_observer", "focus_blueprint"]
