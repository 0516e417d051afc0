"""The Rerun sink: everything the dashboard shows, logged from a worker thread.

The control path never waits for visualisation. The streaming thread hands the sink what it saw
through calls that only append to memory:

* event batches and frames go into one bounded queue; when the worker falls behind, the oldest
  entries are dropped and counted (``frames_dropped``, ``event_batches_dropped`` in :meth:`summary`);
* scalars (exposure, gain, irradiance, rates, latency) go into per-series lists that the worker
  sends as columns every ``flush_period_s`` (a handful of ``send_columns`` calls instead of one
  ``rr.log`` per value); they are never dropped.

Events are drawn as event images (:mod:`necviz.core.event_image`) over windows of
``event_window_us`` sensor time. At most ``max_events_per_window`` are drawn per window: above
that every k-th event is drawn (decimation, counted in ``events_decimated``).
Entity paths follow :mod:`necviz.schema`.
"""

from __future__ import annotations

import math
import threading
import time
from collections import defaultdict, deque

import cv2
import numpy as np
import rerun as rr

from .core.event_image import EventImage
from .core.frames import Frame
from . import schema as S

SATURATED_FRACTION = 0.5  # a frame with more than this fraction of clipped pixels is marked


def _jpeg(image: np.ndarray, quality: int) -> rr.EncodedImage:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise RuntimeError("JPEG encoding failed")
    return rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg")


class RerunSink:
    """Logs a run to a Rerun recording stream from its own thread.

    Parameters
    ----------
    rec : the recording stream (sinks already attached).
    lanes : lane names (entity roots).
    height, width : sensor size (event images).
    event_lanes : lanes whose ``events`` entity shows the shared event stream (default: all).
    event_window_us : sensor time per event image (33 ms: 30 images per second).
    max_events_per_window : decimation cap for drawing events.
    raw_points : if > 0, also log up to this many raw events per window as points.
    queue_size : event batches + frames the queue holds before dropping the oldest.
    jpeg_quality : frames and event images are JPEG-compressed.
    """

    def __init__(self, rec: rr.RecordingStream, lanes, height: int, width: int, event_lanes=None,
                 event_window_us: int = 33_333, max_events_per_window: int = 150_000, raw_points: int = 0,
                 queue_size: int = 4096, flush_period_s: float = 0.1, jpeg_quality: int = 85):
        self.rec = rec
        self.lanes = list(lanes)
        self.event_lanes = list(event_lanes) if event_lanes is not None else list(self.lanes)
        self.event_window_us = int(event_window_us)
        self.max_events_per_window = int(max_events_per_window)
        self.raw_points = int(raw_points)
        self.flush_period_s = float(flush_period_s)
        self.jpeg_quality = int(jpeg_quality)
        self._queue: deque = deque()
        self._queue_size = int(queue_size)
        self._series: dict[str, list] = defaultdict(list)  # path -> [(t_us, value)]
        self._frame_series: dict[str, list] = defaultdict(list)  # path -> [(t_us, seq, value)]
        self._texts: list = []
        self._image = EventImage(height, width)
        self._window_end: int | None = None
        self._window_seen = 0
        self._stride = 1
        self._points: list[np.ndarray] = []
        self._points_kept = 0
        self.stats = {"frames_logged": 0, "events_seen": 0,
                      "events_drawn": 0, "events_decimated": 0, "event_images": 0, "scalars": 0}
        self.dropped = {"frames": 0, "event_batches": 0, "events": 0}  # written by the streaming thread only
        self._wake = threading.Event()
        self._stop = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="necviz-rerun-sink", daemon=True)
        self._thread.start()

    # -- called by the streaming thread (never blocks) ------------------------------------------
    def _push(self, item) -> None:
        q = self._queue
        if len(q) >= self._queue_size:
            old = q.popleft()
            if old[0] == "frame":
                self.dropped["frames"] += 1
            else:
                self.dropped["event_batches"] += 1
                self.dropped["events"] += len(old[1])
        q.append(item)

    def events(self, batch: np.ndarray) -> None:
        if len(batch):
            self._push(("events", batch))

    def frame(self, lane: str, frame: Frame, over: float, under: float) -> None:
        self._push(("frame", lane, frame, over, under))

    def scalar(self, lane: str, leaf: str, t_us: int, value: float, seq: int | None = None) -> None:
        if seq is None:
            self._series[S.path(lane, leaf)].append((t_us, value))
        else:
            self._frame_series[S.path(lane, leaf)].append((t_us, seq, value))

    def text(self, entity: str, t_us: int, message: str, level: str = "INFO") -> None:
        self._texts.append((entity, t_us, message, level))

    # -- worker ---------------------------------------------------------------------------------
    def _run(self) -> None:
        next_flush = time.perf_counter() + self.flush_period_s
        try:
            while True:
                if self._queue:
                    item = self._queue.popleft()
                    if item[0] == "events":
                        self._draw_events(item[1])
                    else:
                        self._log_frame(*item[1:])
                elif self._stop:
                    break
                else:
                    self._wake.wait(0.02)
                    self._wake.clear()
                if time.perf_counter() >= next_flush:
                    self._flush_series()
                    next_flush = time.perf_counter() + self.flush_period_s
            self._close_window(final=True)
            self._flush_series()
        except BaseException as e:  # report in close(); the control path must go on
            self._error = e

    def _draw_events(self, batch: np.ndarray) -> None:
        t = batch["t"]
        if self._window_end is None:
            self._window_end = (int(t[0]) // self.event_window_us + 1) * self.event_window_us
        # split the batch at window ends
        start = 0
        while start < len(batch):
            stop = int(np.searchsorted(t, self._window_end, side="left"))
            if stop >= len(batch):
                self._add_to_window(batch[start:])
                break
            self._add_to_window(batch[start:stop])
            self._close_window()
            start = stop

    def _add_to_window(self, part: np.ndarray) -> None:
        if not len(part):
            return
        self._window_seen += len(part)
        drawn = self._image.add(part, self._stride)
        self.stats["events_drawn"] += drawn
        self.stats["events_decimated"] += len(part) - drawn
        if self.raw_points and self._points_kept < self.raw_points:
            keep = part[:: self._stride][: self.raw_points - self._points_kept]
            self._points.append(keep)
            self._points_kept += len(keep)

    def _close_window(self, final: bool = False) -> None:
        if self._window_end is None:
            return
        end = self._window_end
        seen = self._window_seen
        self.stats["events_seen"] += seen
        if seen or not final:
            self.rec.set_time(S.TIME, duration=end / 1e6)
            img = _jpeg(np.ascontiguousarray(self._image.render()[:, :, ::-1]), self.jpeg_quality)  # RGB -> BGR
            rate = seen / (self.event_window_us / 1e6)
            pts = np.concatenate(self._points) if self._points else None
            for lane in self.event_lanes:
                self.rec.log(S.path(lane, S.EVENTS), img)
                self._series[S.path(lane, S.EVENT_RATE)].append((end, rate))
                if pts is not None and len(pts):
                    colors = np.where(pts["p"][:, None] > 0, [[80, 170, 255]], [[255, 70, 60]]).astype(np.uint8)
                    self.rec.log(S.path(lane, S.EVENT_POINTS),
                                 rr.Points2D(np.stack([pts["x"], pts["y"]], axis=1).astype(np.float32) + 0.5,
                                             colors=colors, radii=0.5))
            self.stats["event_images"] += 1
        # the next window's decimation stride from this window's count
        self._stride = max(1, math.ceil(seen / self.max_events_per_window)) if self.max_events_per_window > 0 else 1
        self._image.clear()
        self._points, self._points_kept = [], 0
        self._window_seen = 0
        self._window_end = end + self.event_window_us

    def _log_frame(self, lane: str, frame: Frame, over: float, under: float) -> None:
        t = frame.exposure_start_us
        self.rec.set_time(S.TIME, duration=t / 1e6)
        self.rec.set_time(S.FRAME, sequence=frame.sequence)
        self.rec.log(S.path(lane, S.FRAME_IMAGE), _jpeg(frame.image, self.jpeg_quality))
        worst = max(over, under)
        if worst > SATURATED_FRACTION:
            kind = "over" if over >= under else "under"
            self.rec.log(S.path(lane, S.SATURATED), rr.Scalars(worst))
            self.rec.log(S.path(lane, S.LOG), rr.TextLog(f"frame {frame.sequence}: {worst:.0%} {kind}-exposed",
                                                         level=rr.TextLogLevel.WARN))
        self.rec.reset_time()
        self.stats["frames_logged"] += 1

    def _flush_series(self) -> None:
        series, self._series = self._series, defaultdict(list)
        fseries, self._frame_series = self._frame_series, defaultdict(list)
        texts, self._texts = self._texts, []
        for p, pts in series.items():
            arr = np.asarray(pts, dtype=np.float64)
            self.rec.send_columns(p, indexes=[rr.TimeColumn(S.TIME, duration=arr[:, 0] / 1e6)],
                                  columns=rr.Scalars.columns(scalars=arr[:, 1]))
            self.stats["scalars"] += len(arr)
        for p, pts in fseries.items():
            arr = np.asarray(pts, dtype=np.float64)
            self.rec.send_columns(p, indexes=[rr.TimeColumn(S.TIME, duration=arr[:, 0] / 1e6),
                                              rr.TimeColumn(S.FRAME, sequence=arr[:, 1].astype(np.int64))],
                                  columns=rr.Scalars.columns(scalars=arr[:, 2]))
            self.stats["scalars"] += len(arr)
        for entity, t_us, msg, level in texts:
            self.rec.set_time(S.TIME, duration=t_us / 1e6)
            self.rec.log(entity, rr.TextLog(msg, level=level))
        if texts:
            self.rec.reset_time()

    # -- shutdown -------------------------------------------------------------------------------
    def close(self) -> dict:
        """Drain the queue, send the last series, flush the recording; returns the stats."""
        if not self._stop:
            self._stop = True
            self._wake.set()
            self._thread.join()
            self.rec.flush()
        if self._error is not None:
            err, self._error = self._error, None
            raise err
        return self.summary()

    def summary(self) -> dict:
        """Counters: what was logged, and what was dropped or decimated to keep up."""
        s = dict(self.stats)
        s["frames_dropped"] = self.dropped["frames"]
        s["event_batches_dropped"] = self.dropped["event_batches"]
        s["events_seen"] += self.dropped["events"]
        s["events_decimated"] += self.dropped["events"]
        return s
