"""The flight recorder: keep the last seconds of a run in bounded memory, write a clip around every failure.

A live session lasts an hour; what matters are the ten seconds around each saturated frame. A
:class:`FlightRecorder` is a pipeline :class:`~necviz.pipeline.Observer` that keeps everything the
observers are told — event batches, markers, frames (with their telemetry), IMU and triggers,
commands, predictions, tuning and other notes — in a ring covering the last ``before_s`` seconds of
sensor time. When a lane's frame is saturated (:class:`~necviz.telemetry.FrameRecord`, more
than half its pixels clipped) or the user types ``mark`` at the tuning prompt, a clip opens over the
window ``[failure - before_s, failure + after_s]`` (the failure: the saturated frame's exposure start,
or the moment of the mark). A failure whose window overlaps the open clip's, in any lane, extends it:
overlapping windows make one clip. The clip is closed once no later failure can overlap it (``before_s``
after its window ends), trimmed to its window and handed to a writer thread, which writes into ``folder``:

* ``<base>-<lane>-<cause>.necrec`` for every lane that failed in the clip: the native recording of
  *that lane's* camera (events, frames, IMU, triggers, the commands of the lane that drives it, every
  note), with the lane's first failure in its header (``clip_failure_us``, ``clip_cause``,
  ``clip_lane``) and the clip's window (``clip_window_*``, ``clip_focus_*``, on the session's time
  axis, ``clip_origin_us``): ``necviz replay`` opens it looping over the same window as the ``.rrd``;
  a clip made by ``mark`` alone keeps the first lane's camera (cause ``mark``);
* ``<base>.rrd``: what the dashboard showed over the clip, every lane, in the session's layout, its
  time panel looping over the second around the first failure.

``<base>`` is the local wall-clock time of the clip's first failure and its sensor time from the start
of the run (``20250101-120301-t812.345s``); ``<cause>`` the diagnosis of the lane's first saturated
frame (:mod:`necviz.core.diagnosis`: ``command_latency``, ``limit_reached`` ...), ``saturated`` when
none was named, or ``mark``.

Memory. ``memory_mb`` (:attr:`ClipOptions.memory_mb`) bounds everything the recorder holds, the writer
included: a quarter of it (at most 32 MB) is kept for the writer's working memory (encoders, Rerun's
batches), the rest bounds the data held — each event batch, frame, IMU batch and note counted once,
whether the ring, the clip being collected, the clips waiting for the writer or the clip being written
holds it. Beyond it the oldest data not being written are dropped first (counted and reported: a clip
then covers less than ``before_s``); a clip that keeps growing (a failure that lasts) is closed at half
the data budget and the next failure starts a new one; at most :data:`MAX_PENDING` clips wait for the
writer (more are dropped and counted). At the DAVIS346's full 12 Mev/s, 5 s of events are 780 MB: size
``--clip-memory`` for the rate you expect. Simulated frames' ground truth is not kept. The streaming
thread only appends to memory; files are written by the writer thread. A run without a failure or a
mark writes nothing. A clip that cannot be written (a full disk) is removed whole and the recorder's
:attr:`~FlightRecorder.failure` says why: the session stops with that one line.
"""

from __future__ import annotations

import dataclasses
import os
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
from necviz.progress import plural

#: Clips waiting for the writer beyond the one being written; more are dropped (and counted).
MAX_PENDING = 2
#: Bytes counted for an entry that holds no array (a command, a prediction, a note).
SMALL = 160
#: Extra sensor time the ring keeps, so a clip still holds ``before_s`` before a saturated frame's
#: exposure *start* when the frame is only known at its end (exposures up to this long).
SLACK_US = 200_000
#: Seconds around the failure the viewer of a clip loops over.
FOCUS_S = 1.0
#: The writer's share of the budget (and its cap): encoders, Rerun's chunk batches, file buffers.
WRITER_SHARE = 0.25
WRITER_CAP = 32 << 20
#: Free space a clip needs on its disk beyond its own bytes before it is written.
CLIP_SPACE_MARGIN = 4 << 20


def cause_slug(cause: str) -> str:
    """A diagnosed cause as a file-name part (``command_latency``); ``saturated`` when none was named."""
    slug = re.sub(r"[^A-Za-z0-9_-]+", "-", str(cause or "").strip()).strip("-")
    return slug or "saturated"


class _Item:
    """One thing the observers were told, with how many holders (ring, clips) keep it."""

    __slots__ = ("args", "method", "nbytes", "refs", "t")

    def __init__(self, t: int, nbytes: int, method: str, args: tuple):
        self.t, self.nbytes, self.method, self.args, self.refs = t, nbytes, method, args, 0


@dataclasses.dataclass
class _Clip:
    start_us: int  # the window: [start_us, end_us] of sensor time
    end_us: int
    wall: float
    items: deque = dataclasses.field(default_factory=deque)
    failures: list = dataclasses.field(default_factory=list)  # (t_us, lane or None for a mark, cause)
    nbytes: int = 0  # what its items count
    trimmed_events: int = 0  # dropped from its head to stay in the budget
    cut: bool = False
    pinned: bool = False  # taken by the writer: never trimmed

    @property
    def first(self) -> tuple:
        return self.failures[0]


def _from(ring, lo: int) -> list:
    """The ring's entries from ``lo`` on, without the end marker, frame and frame record of an exposure
    that started before ``lo`` (a clip never begins inside an exposure)."""
    out, started = [], set()
    for it in ring:
        if it.t < lo:
            continue
        args = it.args
        if it.method == "packet" and isinstance(args[1], ExposureMarker):
            if args[1].kind == "start":
                started.add(args[0])
            elif args[0] not in started:
                continue
        elif it.method == "packet" and isinstance(args[1], Frame) and args[1].exposure_start_us < lo:
            continue
        elif it.method == "frame" and args[1].exposure_start_us < lo:
            continue
        out.append(it)
    return out


class FlightRecorder(Observer):
    """Keeps the last ``before_s`` seconds in bounded memory; writes a clip around every failure.

    Parameters
    ----------
    options : ClipOptions
        Where clips go (``folder``, created if missing by :meth:`ClipOptions.check`, which the command
        runs beforehand), the seconds kept before a failure and recorded after it (``before_s``,
        ``after_s``) and the memory budget (``memory_mb``: everything held, the writer included).
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
        self.labels: dict = {}  # lane -> the name it is shown by (``camera`` as its controller; the session's)
        self.drivers = dict(drivers)
        self.layout = layout
        self.before_us = int(options.before_s * 1e6)
        self.after_us = int(options.after_s * 1e6)
        self.budget = int(options.memory_mb * 2**20)
        self.writer_reserve = min(int(self.budget * WRITER_SHARE), WRITER_CAP)
        self.data_budget = self.budget - self.writer_reserve
        self.properties = dict(properties or {})
        self.event_window_us = int(event_window_ms * 1000)
        self.out = out
        self._ring: deque = deque()
        self._held = 0  # bytes of the items someone holds (each counted once)
        self._clip: _Clip | None = None  # being collected
        self._waiting: deque = deque()  # closed, not yet taken by the writer
        self._now: int | None = None
        self._origin: int | None = None
        self._initial: dict = {}
        self._frame_ids: tuple[int, Frame] | None = None  # the last frame, without its ground truth
        self.failure: BaseException | None = None  # a clip that could not be written (a full disk)
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
        self._lock = threading.Lock()
        self._rec = None  # the writer's Rerun stream, made for the first clip (_stream)
        self._writer = threading.Thread(target=self._write_loop, name="necviz-flight-recorder", daemon=True)
        self._writer.start()

    # -- holding and letting go (under the lock: the writer thread lets go of what it wrote) ---------
    def _hold(self, item: _Item) -> None:
        if item.refs == 0:
            self._held += item.nbytes
        item.refs += 1

    def _release(self, item: _Item, dropped: bool = False) -> None:
        item.refs -= 1
        if item.refs == 0:
            self._held -= item.nbytes
            if dropped:
                self.stats["dropped_bytes"] += item.nbytes
                if item.method == "events":
                    self.stats["dropped_events"] += len(item.args[0])

    def _shed(self) -> None:
        """Over the data budget: let go of the oldest data no writer holds: first the ring's (seconds that
        may precede a failure), then, only when the ring is empty, the oldest of the clips still waiting for
        the writer (a failure already seen is worth more than one that may come; a writer slowed by a busy
        machine must not lose it to the newest data)."""
        while self._held > self.data_budget:
            if self._ring:
                oldest = self._ring
            else:
                holders = [c.items for c in ([self._clip] if self._clip else []) + list(self._waiting) if c.items]
                if not holders:
                    return
                oldest = min(holders, key=lambda d: d[0].t)
            item = oldest.popleft()
            if oldest is not self._ring:
                clip = self._clip if self._clip is not None and oldest is self._clip.items else None
                clip = clip or next(c for c in self._waiting if c.items is oldest)
                clip.nbytes -= item.nbytes
                if item.method == "events":
                    clip.trimmed_events += len(item.args[0])
            self._release(item, dropped=True)
        for c in [c for c in self._waiting if not c.items]:  # trimmed to nothing
            self._waiting.remove(c)
            self.stats["clips_dropped"] += 1

    # -- the ring ---------------------------------------------------------------------------------
    def _add(self, t_us: int | None, nbytes: int, method: str, args: tuple) -> None:
        if t_us is not None and (self._now is None or t_us > self._now):
            self._now = int(t_us)
        now = self._now if self._now is not None else 0
        item = _Item(now if t_us is None else int(t_us), nbytes, method, args)
        with self._lock:
            self._ring.append(item)
            self._hold(item)
            clip = self._clip
            if clip is not None:
                clip.items.append(item)
                clip.nbytes += item.nbytes
                self._hold(item)
            horizon = now - self.before_us - SLACK_US
            ring = self._ring
            while ring and ring[0].t < horizon:
                self._release(ring.popleft())
            self._shed()
            if self._held > self.stats["peak_bytes"]:
                self.stats["peak_bytes"] = self._held
            if clip is not None and clip is self._clip:
                if clip.nbytes > self.data_budget // 2:  # a failure that lasts: cut it here
                    clip.cut = True
                    clip.end_us = min(clip.end_us, item.t)
                    self.stats["clips_cut"] += 1
                    self._close_clip()
                elif now > clip.end_us + self.before_us + SLACK_US:  # no later failure can overlap it
                    self._close_clip()

    def _open(self, failure_us: int, cause: str, lane: str | None) -> None:
        """A failure (or a mark, ``lane`` None) at ``failure_us``: open a clip, or extend the open one."""
        with self._lock:
            clip = self._clip
            lo = failure_us - self.before_us
            if clip is not None and lo <= clip.end_us:  # the windows overlap: one clip
                clip.end_us = max(clip.end_us, failure_us + self.after_us)
                clip.failures.append((failure_us, lane, cause))
                return
            if clip is not None:
                self._close_clip()
            clip = _Clip(lo, failure_us + self.after_us, time.time())
            clip.failures.append((failure_us, lane, cause))
            for it in _from(self._ring, lo):
                clip.items.append(it)
                clip.nbytes += it.nbytes
                self._hold(it)
            self._clip = clip

    def _close_clip(self) -> None:
        """Hand the clip being collected to the writer, trimmed to its window (under the lock)."""
        clip, self._clip = self._clip, None
        if clip is None:
            return
        while clip.items and clip.items[-1].t > clip.end_us:
            clip.nbytes -= clip.items[-1].nbytes
            self._release(clip.items.pop())
        if not clip.items:
            self.stats["clips_dropped"] += 1
            return
        while len(self._waiting) >= MAX_PENDING:  # the writer is behind: the oldest waiting clip goes
            old = self._waiting.popleft()
            while old.items:
                self._release(old.items.popleft(), dropped=True)
            self.stats["clips_dropped"] += 1
        self._waiting.append(clip)
        self._queue.put(True)

    def mark(self, text: str = "") -> str:
        """Open (or extend) a clip now, as for a failure (``mark`` at the tuning prompt; streaming thread)."""
        now = self._now if self._now is not None else 0
        self.stats["marks"] += 1
        self._open(now, "mark", None)
        return (
            f"clip marked at {self._t(now):.3f} s: it keeps {self.before_us / 1e6:g} s before and "
            f"{self.after_us / 1e6:g} s after (longer if a failure follows within {self.before_us / 1e6:g} s); "
            f"it is written to {self.folder} once nothing more joins it, "
            f"{(self.after_us + self.before_us) / 1e6:g} s of sensor time from now at the earliest"
        )

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
        if frame.truth is None:
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
        with self._lock:
            if self._clip is not None:
                self._close_clip()
        self._queue.put(None)
        self._writer.join()
        with self._lock:
            while self._ring:
                self._release(self._ring.popleft())
        return dict(self.stats, buffer_bytes=self.budget)

    # -- the writer thread ------------------------------------------------------------------------
    def _write_loop(self) -> None:
        while True:
            token = self._queue.get()
            while True:
                with self._lock:
                    clip = self._waiting.popleft() if self._waiting else None
                    if clip is not None:
                        clip.pinned = True
                if clip is None:
                    break
                self._write_one(clip)
            if token is None:
                return

    def _write_one(self, clip: _Clip) -> None:
        try:
            if self.failure is None:
                paths = self.write_clip(clip)
                self.stats["clips_written"] += 1
                self.stats["files"] += [str(p) for p in paths]
                if self.out is not None:
                    n = sum(1 for f in clip.failures if f[1] is not None)
                    cams = plural(len(paths) - 1, "camera")
                    print(f"\n  clip: {paths[-1]} ({plural(n, 'failure')}; {cams} in .necrec)", file=self.out)
            else:
                self.stats["clips_dropped"] += 1
        except Exception as e:  # noqa: BLE001 - kept for the session, which stops with its one line
            self.stats["write_errors"] += 1
            self.failure = clip_write_error(self.folder, e)
        finally:
            with self._lock:
                while clip.items:
                    self._release(clip.items.popleft())

    def base_name(self, clip: _Clip) -> str:
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(clip.wall))
        base, k = f"{stamp}-t{self._t(clip.first[0]):.3f}s", 2
        name = base
        while any(self.folder.glob(f"{name}.rrd")) or any(self.folder.glob(f"{name}-*.necrec")):
            name, k = f"{base}-{k}", k + 1
        return name

    def _check_space(self, clip: _Clip) -> None:
        """Refuse a clip its disk cannot hold (its raw bytes, an upper bound of what the files take
        compressed, and a margin) before anything of it is written: a writer that hits a full disk
        half-way reports it in its own words (Rerun's file sink logs its own error line)."""
        import errno

        from necviz.outputs import free_bytes

        need = clip.nbytes + CLIP_SPACE_MARGIN
        free = free_bytes(self.folder)
        if free is not None and free < need:
            raise OSError(
                errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} (a clip needs about {need >> 20} MB, {free >> 20} MB free)"
            )

    def focus(self, clip: _Clip) -> tuple[float, float]:
        """The seconds (session time) the clip's viewers loop over: the second around its first failure,
        inside the data the clip holds."""
        first = clip.first[0]
        lo = max(clip.items[0].t, first - int(FOCUS_S * 1e6))
        hi = min(clip.items[-1].t, first + int(FOCUS_S * 1e6))
        return self._t(lo), self._t(max(hi, lo))

    def write_clip(self, clip: _Clip) -> list[Path]:
        """Write ``clip``: a ``.necrec`` per lane that failed in it (its camera) and the ``.rrd``; returns
        the paths (the ``.rrd`` last). Nothing partial is left when a write fails."""
        from necviz.drivers.recordings.native import Recorder
        from necviz.writers import Pending

        self._check_space(clip)
        base = self.base_name(clip)
        first_lane = next(iter(self.lanes))
        per_lane: dict[str, list] = {}
        for t, lane, cause in clip.failures:
            per_lane.setdefault(lane or first_lane, []).append((t, cause if lane is not None else "mark"))
        start, end = clip.items[0].t, clip.items[-1].t
        focus = self.focus(clip)
        window = {
            "clip_origin_us": self._origin if self._origin is not None else start,
            "clip_window_start_us": start,
            "clip_requested_start_us": clip.start_us,  # first failure - before_s: later start = data dropped
            "clip_window_end_us": end,
            "clip_focus_start_s": round(focus[0], 6),
            "clip_focus_end_s": round(focus[1], 6),
            "clip_failures_all": len([f for f in clip.failures if f[1] is not None]),
            "clip_marks": len([f for f in clip.failures if f[1] is None]),
            "clip_lanes_failed": ",".join(per_lane),
            "clip_rrd": f"{base}.rrd",
            "clip_cut": clip.cut,
            "clip_dropped_events": clip.trimmed_events,
        }
        pending, observers, recorders = [], [], []
        try:
            for lane, fails in per_lane.items():
                camera = self.lanes.get(lane, lane)
                t0, cause = fails[0]
                props = {
                    **{k: str(v) for k, v in self.properties.items()},
                    **window,
                    "clip_lane": lane,
                    "clip_camera": camera,
                    "clip_cause": cause or "saturated",
                    "clip_failure_us": t0,
                    "clip_failure_s": round(self._t(t0), 6),
                    "clip_failures": len(fails),
                }
                p = Pending(self.folder / f"{base}-{cause_slug(lane)}-{cause_slug(cause)}.necrec")
                pending.append(p)
                rec = Recorder(p.tmp, sensor=self.sensor, properties=props)
                recorders.append(rec)
                observers.append(RecorderObserver(rec, camera, self.drivers.get(camera, lane)))
            rrd = Pending(self.folder / f"{base}.rrd")
            pending.append(rrd)
            self._write(clip, observers, rrd.tmp, {**window, "clip_cause": clip.first[2] or "saturated"}, focus)
            for rec in recorders:
                rec.close()
            for p in pending:
                p.commit()
        except BaseException:
            for rec in recorders:
                try:
                    rec.close()
                except BaseException:  # noqa: BLE001 - the first error is the one reported
                    pass
            for p in pending:
                p.abort()
            raise
        return [p.path for p in pending]

    def _stream(self):
        """The Rerun recording stream every clip of the session is written through, one file after the
        other: rerun-sdk 0.41 keeps most of what a stream logged resident after it is disconnected
        (measured: +5 MB per 6 MB clip with a new stream per clip, flat with one reused), so a new stream
        per clip would grow the writer by every clip. The clips share its recording id."""
        if self._rec is None:
            import uuid

            import rerun as rr

            batching = rr.ChunkBatcherConfig(flush_tick=2.0, flush_num_bytes=1 << 20, flush_num_rows=100_000)
            self._rec = rr.RecordingStream("necviz", recording_id=str(uuid.uuid4()), batcher_config=batching)
        return self._rec

    def _write(self, clip: _Clip, observers: list, path: Path, props: dict, focus: tuple) -> None:
        """Replay the clip into the native recorders and a Rerun sink writing ``path`` (one pass)."""
        import rerun as rr

        from necviz.dashboard.sink import RerunSink, SinkOptions
        from necviz.layouts import style_series

        names = list(self.lanes)
        origin = self._origin if self._origin is not None else clip.items[0].t
        data = path.with_name(path.name + ".data")
        layout = path.with_name(path.name + ".rbl")
        rec = self._stream()
        rec.set_sinks(rr.FileSink(str(data)))
        try:
            t = self._t(clip.first[0])
            rec.send_recording_name(f"necviz clip: {clip.first[2] or 'saturated'} at {t:.3f} s")
            rec.send_property("run", rr.AnyValues(**{k: str(v) for k, v in props.items()}, layout=self.layout))
            style_series(rec, names, self.labels)
            options = SinkOptions(
                event_window_us=self.event_window_us,
                origin_us=origin,
                lossless=True,
                queue_size=64,
                frame_queue_size=4,
                image_chunk_bytes=256 << 10,
            )
            sink = RerunSink(rec, names, self.sensor.height, self.sensor.width, options)
            sink.started(clip.items[0].t, self._initial)
            for obs in [*observers, sink]:
                for it in clip.items:
                    getattr(obs, it.method)(*it.args)
            sink.close()
            rec.flush()
            rr.disconnect(rec)
            save_blueprint_apart(layout, self.layout, names, self.sensor.width, self.sensor.height, focus, self.labels)
            from necviz.dashboard.rrd_file import join_segments

            join_segments([data, layout], path)  # the clip's data and its layout, one file
        finally:
            rr.disconnect(rec)
            data.unlink(missing_ok=True)
            layout.unlink(missing_ok=True)


def save_blueprint_apart(
    path: Path, layout: str, lanes: list, width: int, height: int, focus: tuple, labels: dict | None = None
) -> None:
    """Write the clip's layout, looping over ``focus``, as a blueprint file (``.rbl``), in a child process.

    rerun-sdk 0.41 creates a recording stream for every blueprint it writes and keeps most of its memory
    after it is closed (~1-2.5 MB per blueprint, measured): a blueprint per clip written in the session's
    process would grow it by every clip. The child takes that memory with it when it ends."""
    import json
    import subprocess
    import sys

    spec = json.dumps(
        {"path": str(path), "layout": layout, "lanes": lanes, "size": [width, height], "focus": focus, "labels": labels}
    )
    proc = subprocess.run(
        [sys.executable, "-m", "necviz.dashboard.flight_recorder", spec],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0 or not path.is_file():
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        raise RuntimeError(f"the clip's layout could not be written ({lines[-1] if lines else proc.returncode})")


def _blueprint_child(spec_json: str) -> int:
    """``python -m necviz.dashboard.flight_recorder SPEC``: :func:`save_blueprint_apart`'s child."""
    import json

    from necviz.layouts import make_blueprint
    from necviz.layouts.focus import focus_blueprint

    spec = json.loads(spec_json)
    w, h = spec["size"]
    bp = focus_blueprint(make_blueprint(spec["layout"], spec["lanes"], w, h, spec.get("labels")), *spec["focus"])
    bp.save("necviz", spec["path"])
    return 0


def clip_write_error(folder, exc: BaseException):
    """The one-line error of a clip that could not be written (nothing of it is left)."""
    from necviz.outputs import OutputError
    from necviz.writers import write_failure

    cause = write_failure(exc) or exc
    what = getattr(cause, "strerror", None) or " ".join(str(cause).split()) or type(cause).__name__
    return OutputError(f"--clips: cannot write a clip to {str(folder)!r}: {what}; nothing of it was left there")


def clip_focus(properties: dict) -> tuple[float, float, float, int] | None:
    """A clip's declared window as its replay shows it: ``(focus start s, focus end s, failure s,
    origin µs)`` on the session's time axis (what the clip's ``.rrd`` loops over), or None for a
    recording that is not a clip."""
    try:
        origin = int(properties["clip_origin_us"])
        lo, hi = float(properties["clip_focus_start_s"]), float(properties["clip_focus_end_s"])
        failure = (int(properties["clip_failure_us"]) - origin) / 1e6
    except (KeyError, TypeError, ValueError):
        return None
    return lo, hi, failure, origin


def clip_observer(options):
    """A session observer factory (:class:`necviz.dashboard.session.Session` ``observers``) for
    :class:`~necviz.options.ClipOptions`: a :class:`FlightRecorder` on the session's lanes and layout."""

    def make(session, layout: str, out):
        from necviz.dashboard.session import lane_labels

        lanes = {ln.name: ln.camera or ln.name for ln in session.lanes}
        drivers = {}
        for ln in session.lanes:
            if ln.drives:
                drivers.setdefault(ln.camera or ln.name, ln.name)
        recorder = FlightRecorder(
            options,
            sensor=session.source.sensor,
            lanes=lanes,
            drivers=drivers,
            layout=layout,
            properties=session.properties,
            event_window_ms=session.show.event_window_ms,
            out=out,
        )
        recorder.labels = lane_labels(session.lanes)
        return recorder

    return make


__all__ = [
    "FlightRecorder",
    "MAX_PENDING",
    "cause_slug",
    "clip_focus",
    "clip_observer",
    "clip_write_error",
    "plural",
]


if __name__ == "__main__":
    import sys

    sys.exit(_blueprint_child(sys.argv[1]))
