"""``--video OUT.mp4``: an H.264 video of what the dashboard shows, for talks, papers and colleagues.

:class:`VideoWriter` is a pipeline :class:`~necviz.pipeline.Observer`. Every video frame shows, as of
one instant of sensor time:

* each lane's newest APS frame, side by side, under a bar with the lane's name, exposure and gain
  (the bar turns red while the frame is saturated, more than half its pixels clipped);
* under each frame its **over-exposure strip**: a few columns per video frame, scrolling left, red as
  high as the fraction of over-exposed pixels (> 249 DN) and blue as high as the under-exposed (< 10 DN);
* the shared **event image** of the last ``event_window_ms`` (ON blue, OFF red, as in the dashboard);
* the **sensor time** and the playback speed.

Time: video frame ``k`` shows sensor time ``t0 + k * speed / fps``; ``speed`` 1 plays in real time,
0.1 ten times slower (slow motion). Panels are laid out in a grid of at most four columns; the size
is rounded up to even numbers (H.264 in 4:2:0). Encoding (PyAV: FFmpeg's libx264 in its wheel; the
optional extra ``video``) runs on a worker thread; the streaming thread only hands packets over and
waits when 64 are queued (a file output loses nothing). The file is written beside its name and
renamed when complete.
"""

from __future__ import annotations

import math
import os
import queue
import threading
from collections import deque
from fractions import Fraction

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.event_image import EventImage
from necviz.pipeline import Observer

LABEL_H = 20  # px: the bar with the lane's name above each panel
STRIP_H = 16  # px: the over-exposure strip under each frame
STRIP_STEP = 3  # px of strip per video frame
HEADER_H = 24  # px: the sensor time above the grid
COLUMNS = 4
OVER, UNDER = 249, 10  # DN: clipped pixels (the telemetry's thresholds)


def exposure_text(exposure_us: float) -> str:
    """An exposure for a frame's label: ``12.50 ms``, ``850 us``, ``4.0 us`` (the label's font has no µ;
    below 1 ms in microseconds, so 4 µs does not read ``0.00 ms``)."""
    if exposure_us >= 1000:
        return f"{exposure_us / 1000:.2f} ms"
    return f"{exposure_us:.0f} us" if exposure_us >= 10 else f"{exposure_us:.1f} us"


def require_av():
    """PyAV, or a one-line error saying how to install it."""
    try:
        import av
    except ImportError:
        raise ParameterError("--video needs PyAV (FFmpeg in a wheel): pip install 'necviz[video]'") from None
    return av


class Canvas:
    """The video frame's layout: a header, then panels (lanes' frames and the event image) in a grid."""

    def __init__(self, names: list[str], width: int, height: int):
        self.names = list(names)
        self.w, self.h = int(width), int(height)
        n = len(self.names) + 1  # + the event image
        self.cols = min(n, COLUMNS)
        self.rows = math.ceil(n / self.cols)
        self.cell_h = LABEL_H + self.h + STRIP_H
        self.width = self.cols * self.w + (self.cols * self.w) % 2
        self.height = HEADER_H + self.rows * self.cell_h
        self.height += self.height % 2

    def cell(self, i: int) -> tuple[int, int]:
        """Top-left corner (x, y) of panel ``i`` (lanes first, then the event image)."""
        return (i % self.cols) * self.w, HEADER_H + (i // self.cols) * self.cell_h


def _text(img, text: str, x: int, y: int, colour=(230, 230, 230), scale: float = 0.45) -> None:
    import cv2

    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


class VideoWriter(Observer):
    """Render the run into an H.264 MP4 (layout and timing in the module docstring).

    Parameters
    ----------
    path : the ``.mp4`` to write (checked beforehand with :func:`necviz.outputs.check_output`).
    lanes : lane names, in display order.
    width, height : the sensor size.
    speed : video time per sensor time (0.1: ten times slower than real).
    fps : video frames per second.
    event_window_ms : sensor time drawn in the event image.
    crf : x264 quality (lower: better and bigger; 18 is visually lossless, 23 x264's default).

    Raises
    ------
    ParameterError
        If PyAV is not installed, or for a speed or frame rate that is not positive.
    """

    name = "video"

    def __init__(
        self,
        path,
        lanes,
        width: int,
        height: int,
        *,
        speed: float = 1.0,
        fps: float = 30.0,
        event_window_ms: float = 33.3,
        crf: int = 20,
    ):
        self.av = require_av()
        from necviz.writers import Pending

        if not (speed > 0 and fps > 0):
            raise ParameterError(f"video speed and frame rate must be positive, got x{speed}, {fps} fps")
        self.path = path
        self.canvas = Canvas(list(lanes), width, height)
        self.speed = float(speed)
        self.fps = Fraction(fps).limit_denominator(1001)
        self.step_us = self.speed * 1e6 / float(self.fps)  # sensor µs per video frame
        self.window_us = int(event_window_ms * 1000)
        self.crf = int(crf)
        self._pending = Pending(path)
        self._q: queue.Queue = queue.Queue(maxsize=64)
        self._error: BaseException | None = None
        self.frames = 0
        self._thread = threading.Thread(target=self._run, name="necviz-video", daemon=True)
        self._thread.start()

    # -- observer (streaming thread): hand over ---------------------------------------------------
    def _put(self, item) -> None:
        if self._error is None:
            self._q.put(item)

    def started(self, t_us, initial):
        self._put(("start", int(t_us)))

    def events(self, batch):
        if len(batch):
            self._put(("events", batch))

    def frame(self, lane, frame, record):
        self._put(("frame", lane, frame.image, int(frame.exposure_end_us), frame.exposure_us, frame.gain, record))

    def close(self):
        """Render up to the last sensor time seen, finish the file and return its statistics."""
        self._q.put(None)
        self._thread.join()
        if self._error is not None:
            self._pending.abort()
            err = self._error
            if isinstance(err, OSError) and not isinstance(err, (FileNotFoundError, PermissionError)):
                from necviz.outputs import write_failed  # a full disk: name the file asked for, not its temporary twin

                raise write_failed(self.path, err, os.path.exists(self.path), "--video") from None
            raise err
        self._pending.commit()
        duration = self.frames / float(self.fps)
        return {
            "path": str(self.path),
            "frames": self.frames,
            "duration_s": duration,
            "speed": self.speed,
            "fps": float(self.fps),
            "width": self.canvas.width,
            "height": self.canvas.height,
        }

    # -- worker: render and encode ----------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._encode()
        except BaseException as e:  # reported by close(); the streaming thread must not block on a dead worker
            self._error = e
            while True:
                try:
                    if self._q.get_nowait() is None:
                        break
                except queue.Empty:
                    if not self._thread.is_alive():
                        break
                    continue

    def _encode(self) -> None:
        av = self.av
        c = self.canvas
        container = av.open(str(self._pending.tmp), mode="w", format="mp4")
        try:
            stream = container.add_stream("libx264", rate=self.fps)
            stream.width, stream.height = c.width, c.height
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(self.crf), "preset": "veryfast"}
            state = _State(c, self.window_us)
            t0 = next_t = None
            while True:
                item = self._q.get()
                if item is None:
                    break
                kind = item[0]
                if kind == "start":
                    t0 = next_t = item[1]
                    continue
                t = int(item[1]["t"][-1]) if kind == "events" else item[3]
                if t0 is None:
                    t0 = next_t = t
                while t > next_t:  # everything up to next_t has arrived: draw that instant
                    self._emit(container, stream, state.render(next_t, next_t - t0, self.speed))
                    next_t = t0 + (self.frames) * self.step_us
                if kind == "events":
                    state.events(item[1])
                else:
                    state.frame(*item[1:])
            if t0 is not None and state.last_t is not None:
                while next_t <= state.last_t:
                    self._emit(container, stream, state.render(next_t, next_t - t0, self.speed))
                    next_t = t0 + self.frames * self.step_us
            for packet in stream.encode(None):
                container.mux(packet)
        finally:
            container.close()

    def _emit(self, container, stream, rgb: np.ndarray) -> None:
        frame = self.av.VideoFrame.from_ndarray(rgb, format="rgb24")
        frame.pts = self.frames
        for packet in stream.encode(frame):
            container.mux(packet)
        self.frames += 1


class _State:
    """What the video shows at an instant: each lane's newest frame and strip, the recent events."""

    def __init__(self, canvas: Canvas, window_us: int):
        self.c = canvas
        self.window_us = window_us
        self.latest: dict[str, tuple] = {}  # lane -> (grey image, end µs, exposure µs, gain, saturated)
        self.pending: dict[str, deque] = {n: deque() for n in canvas.names}  # frames not yet shown
        self.rates: dict[str, tuple[float, float]] = {n: (0.0, 0.0) for n in canvas.names}
        self.strips = {n: np.zeros((STRIP_H, canvas.w, 3), np.uint8) for n in canvas.names}
        self.batches: deque = deque()
        self.image = EventImage(canvas.h, canvas.w)
        self.last_t: int | None = None

    def events(self, batch: np.ndarray) -> None:
        self.batches.append(batch)
        self.last_t = max(self.last_t or 0, int(batch["t"][-1]))

    def frame(self, lane, image, end_us, exposure_us, gain, record) -> None:
        if lane in self.pending:
            self.pending[lane].append((image, end_us, exposure_us, gain, record))
            self.last_t = max(self.last_t or 0, end_us)

    def render(self, t_us: float, elapsed_us: float, speed: float) -> np.ndarray:
        c = self.c
        canvas = np.full((c.height, c.width, 3), 18, np.uint8)
        for i, name in enumerate(c.names):
            q = self.pending[name]
            while q and q[0][1] <= t_us:  # the newest frame whose exposure has ended by now
                img, end, exp, gain, rec = q.popleft()
                self.latest[name] = (img, end, exp, gain, rec.saturated)
                self.rates[name] = (rec.over_exposed_rate, rec.under_exposed_rate)
            x, y = c.cell(i)
            shown = self.latest.get(name)
            sat = bool(shown and shown[4])
            canvas[y : y + LABEL_H, x : x + c.w] = (150, 40, 35) if sat else (45, 45, 45)
            label = name if shown is None else f"{name}  {exposure_text(shown[2])}  x{shown[3]:.2g}"
            _text(canvas, label, x + 5, y + LABEL_H - 6)
            if shown is not None:
                canvas[y + LABEL_H : y + LABEL_H + c.h, x : x + c.w] = shown[0][..., None]
            strip = self.strips[name]
            strip[:, :-STRIP_STEP] = strip[:, STRIP_STEP:]  # scroll left one step per video frame
            over, under = self.rates[name]
            col = np.zeros((STRIP_H, 3), np.uint8)
            n_over, n_under = int(round(over * STRIP_H)), int(round(under * STRIP_H))
            col[STRIP_H - n_over :, 0] = 230
            col[:n_under, 2] = 230
            strip[:, -STRIP_STEP:] = col[:, None]
            canvas[y + LABEL_H + c.h : y + c.cell_h, x : x + c.w] = strip
        # the shared event image over [t - window, t]
        lo = t_us - self.window_us
        while self.batches and int(self.batches[0]["t"][-1]) < lo:
            self.batches.popleft()
        self.image.clear()
        for b in self.batches:
            t = b["t"]
            part = b[(t >= lo) & (t <= t_us)] if (t[0] < lo or t[-1] > t_us) else b
            if len(part):
                self.image.add(part)
        x, y = c.cell(len(c.names))
        canvas[y : y + LABEL_H, x : x + c.w] = (45, 45, 45)
        _text(canvas, f"events (last {self.window_us / 1000:g} ms)", x + 5, y + LABEL_H - 6)
        canvas[y + LABEL_H : y + LABEL_H + c.h, x : x + c.w] = self.image.render()
        _text(canvas, f"t = {elapsed_us / 1e6:8.3f} s sensor time   x{speed:g}", 6, HEADER_H - 7, scale=0.55)
        return canvas


def plan(show, video, viewer):
    """``(show, video)`` for a run that writes ``video``: the video's speed is its own, else the run's
    ``--speed`` when that is a number, else 1; when only files are written (no viewer watches) the run
    itself goes as fast as it can. Checks that PyAV is installed."""
    from dataclasses import replace

    require_av()
    if video.speed is None:
        video = replace(video, speed=float(show.speed) if isinstance(show.speed, (int, float)) else 1.0)
    if not viewer.watched:
        show = replace(show, speed="auto")
    return show, video


def video_observer(options):
    """A session observer factory for :class:`~necviz.options.VideoOptions` (after :func:`plan`)."""
    require_av()

    def make(session, layout, out):
        speed = options.speed if options.speed is not None else 1.0
        sensor = session.source.sensor
        return VideoWriter(
            options.path,
            [ln.name for ln in session.lanes],
            sensor.width,
            sensor.height,
            speed=speed,
            fps=options.fps,
            event_window_ms=session.show.event_window_ms,
        )

    return make


__all__ = ["Canvas", "VideoWriter", "plan", "require_av", "video_observer"]
