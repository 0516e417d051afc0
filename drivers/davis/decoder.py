"""DAVIS 16-bit word stream → events, exposure markers, frames, IMU samples and triggers.

The bulk endpoint delivers little-endian 16-bit words (layout: libcaer's event translator in
``src/davis_common.h``, github.com/inivation/libcaer; summarised in docs/davis-protocol.md).
:func:`decode_words` (:mod:`.decoder_kernels`, re-exported here) is a Numba state machine that walks the
words once — its word-by-word rules (time, DVS, APS frames, IMU, triggers) are documented there;
:class:`DavisDecoder` keeps its state between calls (so a stream split at any byte decodes exactly as
the unsplit stream) and turns its output into packets in stream order (see :mod:`necviz.drivers.source`).

Packets (:meth:`DavisDecoder.decode`): event batches are split only at exposure markers, frames and
timestamp resets (and at 65,536 events); IMU samples and other triggers are gathered per call and
delivered before the next marker/frame or after the call's events, so they never fragment event batches.

Frames are accepted as libcaer's ``apsEndFrame`` (``src/davis_common.h``) accepts them: by their column
counts alone; ROI and exposure-value words may come before or after the frame start.

Exposure markers: special 14 (inside a frame) emits ``start``; special 15 emits ``end`` at its
time; a stream without these specials has its exposures placed by the decoder (see
:mod:`.decoder_kernels`). Markers and events together never go back in time, and an ``end`` is always after its
``start``: when the end arrives within the µs its exposure started (a sub-µs exposure), its marker
is due at start + 1 µs, which is later than the events that may still follow at the current µs, so
it is held (the exposure is "pending") and emitted as soon as a timestamp or wrap word moves time
past the start — before any event of the new time. If a new frame starts or the timestamps reset
while an exposure is open, an ``end`` marker closes it the same way (``exposures_aborted``), so
markers always come in start/end pairs. A frame is emitted after its end marker; a frame whose end
marker is still pending at its frame-end word (read out within one µs: garbage) is dropped.

The decoder never raises on stream content: garbage is skipped and counted (``skipped_words``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.drivers.davis.color import COLOR_FILTERS, demosaic_to_gray8, is_bayer
from necviz.drivers.davis.decoder_kernels import (
    MK_EXPOSURE_END,
    MK_EXPOSURE_START,
    MK_IMU,
    MK_TRIGGER,
    S_EXPO_ABORTED,
    S_EXPO_OPEN,
    S_EXPO_OPEN_T,
    S_F_CYC,
    S_F_EE,
    S_F_ES,
    S_FRAMES_DROPPED,
    S_IMU_DROPPED,
    S_IN_FRAME,
    S_LAST_Y,
    S_NEV,
    S_NMK,
    S_NO_EXPOSURE,
    S_NOW,
    S_OFFSET,
    S_ROI,
    S_RTYPE,
    S_SIZE,
    S_SKIPPED,
    S_TIME_REG,
    S_WORDS,
    TRIG_RESET,
    decode_words,
)

__all__ = ["DavisDecoder", "DecoderOptions"]


_IMU_FIELDS = ("ax", "ay", "az", "gx", "gy", "gz", "temp")


@dataclass(frozen=True)
class DecoderOptions:
    """The format of one DAVIS stream, as the device's registers describe it (validated here, once).

    Parameters
    ----------
    width, height : int
        DVS array size (``SIZE_COLUMNS``/``SIZE_ROWS`` of the DVS module), 1..4096.
    aps_width, aps_height : int, optional
        APS array size, 1..4096 (default: the DVS size).
    dvs_invert_xy : bool
        DVS orientation bit 2 (row words carry x).
    aps_orientation : int
        APS ``ORIENTATION_INFO`` (bit2 invertXY, bit1 flipX, bit0 flipY; the low 3 bits are used).
    imu_orientation : int
        IMU ``ORIENTATION_INFO`` (bit2 flipX, bit1 flipY, bit0 flipZ; the low 3 bits are used).
    imu_model : int
        1 (MPU6050/6150) or 2 (MPU9250): selects the temperature formula.
    adc_shift : int
        Left shift of the ADC samples (1 on DAVIS240, as libcaer doubles them).
    color_filter : int
        APS ``COLOR_FILTER`` (0 mono; 1..4 the Bayer layouts, whose frames are demosaiced to grey as
        libcaer does, :mod:`.color`; 5..8 RGBW, left as they are).

    Raises
    ------
    ParameterError
        An array size that is not an integer in 1..4096, or an unknown colour filter.
    """

    width: int = 346
    height: int = 260
    aps_width: int | None = None
    aps_height: int | None = None
    dvs_invert_xy: bool = False
    aps_orientation: int = 0
    imu_orientation: int = 0
    imu_model: int = 1
    adc_shift: int = 0
    color_filter: int = 0

    def __post_init__(self) -> None:
        if self.color_filter not in COLOR_FILTERS:
            raise ParameterError(f"unknown APS colour filter {self.color_filter!r}; known: {sorted(COLOR_FILTERS)}")
        aps_width = self.width if self.aps_width is None else self.aps_width
        aps_height = self.height if self.aps_height is None else self.aps_height
        sizes = {"width": self.width, "height": self.height, "aps_width": aps_width, "aps_height": aps_height}
        for label, v in sizes.items():
            if not isinstance(v, (int, np.integer)) or not 0 < v <= 4096:
                raise ParameterError(f"decoder {label} must be an integer in 1..4096, got {v!r}")
            object.__setattr__(self, label, int(v))
        object.__setattr__(self, "dvs_invert_xy", bool(self.dvs_invert_xy))
        object.__setattr__(self, "aps_orientation", int(self.aps_orientation) & 7)
        object.__setattr__(self, "imu_orientation", int(self.imu_orientation) & 7)

    @property
    def aps_shape(self) -> tuple[int, int]:
        """``(aps_height, aps_width)``: the APS image shape."""
        return int(self.aps_height or self.height), int(self.aps_width or self.width)

    def config(self) -> np.ndarray:
        """The configuration vector :func:`decode_words` reads."""
        return np.array(
            [
                self.width,
                self.height,
                int(self.dvs_invert_xy),
                self.aps_width,
                self.aps_height,
                self.aps_orientation,
                self.imu_orientation,
                self.imu_model,
                self.adc_shift,
            ],
            np.int64,
        )


class DavisDecoder:
    """Resumable decoder for one DAVIS stream: feed raw transfer bytes, get packets in stream order.

    Parameters
    ----------
    options : DecoderOptions, optional
        The stream's format (default: ``DecoderOptions()``, a DAVIS346).
    time_offset_us : int
        Added to every output time (used to continue a stream after a reconnect).

    Raises
    ------
    ParameterError
        ``options`` that is not a :class:`DecoderOptions`.

    :meth:`decode` accepts any bytes-like object; an odd trailing byte is kept for the next call.
    Frames come out as ``Frame(Z8, exposure_start_us, exposure_end_us, gain=1.0, sequence)`` with
    ``Z8 = CDS10 >> 2`` (a colour sensor's mosaic demosaiced to grey first) in image coordinates
    (top-left origin); ``last_frame_exposure_cycles`` is the exposure the device reported for the
    last frame (ADC cycles, -1 if absent).
    """

    def __init__(self, options: DecoderOptions | None = None, *, time_offset_us: int = 0):
        options = DecoderOptions() if options is None else options
        if not isinstance(options, DecoderOptions):
            raise ParameterError(f"DavisDecoder takes DecoderOptions, got {type(options).__name__}")
        self.options = options
        self.width, self.height = options.width, options.height
        self.aps_shape = options.aps_shape
        self.cfg = options.config()
        self.st = np.zeros(S_SIZE, np.int64)
        self.st[S_LAST_Y] = -1
        self.st[S_RTYPE] = -1
        self.st[S_OFFSET] = int(time_offset_us)
        self._reset_buf = np.zeros(self.aps_shape[0] * self.aps_shape[1], np.int64)
        self._frame = np.zeros(self.aps_shape, np.uint16)  # the frame being assembled: 10-bit CDS values
        self._frame_flat = self._frame.reshape(-1)
        self._carry = b""
        #: events per kernel call (so no event batch is longer than this)
        self.max_batch = 1 << 16
        self._mk = np.empty((4096, 4), np.int64)
        self._imu_t = np.empty(1024, np.int64)
        self._imu_v = np.empty((1024, 7), np.float32)
        self.frames = 0
        self.events = 0
        self.imu_samples = 0
        self.triggers = 0
        self.last_frame_exposure_cycles = -1
        #: exposure cycles (misc10) of each frame, by frame sequence number (kept for the last 64)
        self.frame_cycles: dict[int, int] = {}

    # -- statistics -----------------------------------------------------------------------------
    @property
    def time_us(self) -> int:
        """Current stream time (µs, offset included): the time of the last timestamp seen."""
        return int(self.st[S_OFFSET] + self.st[S_NOW])

    @property
    def stats(self) -> dict:
        st = self.st
        return {
            "words": int(st[S_WORDS]),
            "events": self.events,
            "frames": self.frames,
            "frames_dropped": int(st[S_FRAMES_DROPPED]),
            "frames_without_exposure": int(st[S_NO_EXPOSURE]),
            "imu_samples": self.imu_samples,
            "imu_dropped": int(st[S_IMU_DROPPED]),
            "triggers": self.triggers,
            "skipped_words": int(st[S_SKIPPED]),
            "time_regressions": int(st[S_TIME_REG]),
            "exposures_aborted": int(st[S_EXPO_ABORTED]),
        }

    # -- decoding -------------------------------------------------------------------------------
    def words_of(self, data) -> np.ndarray:
        """The complete little-endian words in ``carry + data``; keeps an odd trailing byte."""
        if isinstance(data, np.ndarray) and data.dtype == np.uint16 and not self._carry:
            return data
        raw = bytes(memoryview(data).cast("B")) if not isinstance(data, bytes) else data
        if self._carry:
            raw = self._carry + raw
        cut = len(raw) & ~1
        self._carry = raw[cut:]
        return np.frombuffer(raw, "<u2", count=cut // 2)

    def decode(self, data) -> list:
        """Decode one transfer (bytes-like, or a uint16 word array); return its packets in order.

        Packets: event batches as bare EVENT_DTYPE arrays (:class:`~necviz.drivers.davis.camera.DavisCamera`
        cuts them into :class:`~necviz.core.events.EventBatch` packets of its batch period), :class:`ExposureMarker`,
        :class:`Frame`, :class:`ImuBatch` (one per sample run between other packets) and :class:`TriggerBatch`.
        """
        words = self.words_of(data)
        out: list = []
        n = words.shape[0]
        pos = 0
        mk, imu_t, imu_v = self._mk, self._imu_t, self._imu_v
        while pos < n:
            ev = np.empty(min(n - pos, self.max_batch), EVENT_DTYPE)
            pos = decode_words(words, pos, self.st, self.cfg, ev, mk, imu_t, imu_v, self._reset_buf, self._frame_flat)
            self._emit(out, ev[: self.st[S_NEV]], mk[: self.st[S_NMK]], imu_t, imu_v)
        return out

    def finish(self) -> list:
        """End of this stream (device unplugged or stopped): close an exposure left open with an ``end``
        marker (at least 1 µs after its start; counted in ``exposures_aborted``), deliver an ``end``
        marker still pending (start + 1 µs: nothing follows it now) and drop a partial frame, so the
        packets delivered keep pairing start/end markers. Returns the packets to deliver."""
        st = self.st
        out = []
        if st[S_EXPO_OPEN] == 1:
            out.append(ExposureMarker(int(max(self.time_us, st[S_EXPO_OPEN_T] + 1)), "end"))
            st[S_EXPO_OPEN] = 0
            st[S_EXPO_ABORTED] += 1
        elif st[S_EXPO_OPEN] == 2:
            out.append(ExposureMarker(int(st[S_EXPO_OPEN_T] + 1), "end"))
            st[S_EXPO_OPEN] = 0
        if st[S_IN_FRAME] == 1:
            st[S_IN_FRAME] = 0
            st[S_FRAMES_DROPPED] += 1
        return out

    def _image(self) -> np.ndarray:
        """The completed frame's 8-bit image: ``Z10 >> 2``, or a colour sensor's ROI demosaiced to grey
        (:func:`~.color.demosaic_to_gray8`, the ROI's first pixel fixing the filter's phase)."""
        z = self._frame
        cf = self.options.color_filter
        if not is_bayer(cf):
            return (z >> 2).astype(np.uint8)
        c0, r0, c1, r1 = (int(v) for v in self.st[S_ROI : S_ROI + 4])
        img = np.zeros(self.aps_shape, np.uint8)
        img[r0 : r1 + 1, c0 : c1 + 1] = demosaic_to_gray8(z[r0 : r1 + 1, c0 : c1 + 1], cf, c0, r0)
        return img

    def _emit(self, out: list, ev: np.ndarray, mk: np.ndarray, imu_t, imu_v) -> None:
        """Packets of one kernel call in stream order.

        Events are split only at exposure markers, frames and timestamp resets. IMU samples and other
        triggers do not split event batches: they are gathered and delivered (each kind as one batch, in
        time order) right before the next marker/frame/reset, or after the call's last events — at most
        one transfer later than the events around them. Consumers that ignore them see unfragmented event
        batches. A timestamp reset is delivered alone, after everything decoded before it and before
        anything after it: libcaer commits the packets before a reset and sends the reset in a container of
        its own (``containerGenerationExecute``, ``src/container_generation.h``).
        """
        self.events += ev.size
        done = 0
        imu_a = imu_b = -1
        trig: list[tuple[int, int]] = []

        def flush_side():
            nonlocal imu_a, imu_b
            if imu_b > imu_a:
                s = np.empty(imu_b - imu_a, IMU_DTYPE)
                s["t"] = imu_t[imu_a:imu_b]
                v = imu_v[imu_a:imu_b]
                for j, name in enumerate(_IMU_FIELDS):
                    s[name] = v[:, j]
                out.append(ImuBatch(s))
                self.imu_samples += imu_b - imu_a
                imu_a = imu_b = -1
            if trig:
                out.append(TriggerBatch(np.array(trig, TRIGGER_DTYPE)))
                self.triggers += len(trig)
                trig.clear()

        for kind, t, at, aux in mk.tolist():
            if kind == MK_IMU:  # samples of one call are numbered consecutively
                if imu_a < 0:
                    imu_a = aux
                imu_b = aux + 1
                continue
            if kind == MK_TRIGGER and aux != TRIG_RESET:
                trig.append((t, aux))
                continue
            if at > done:
                out.append(ev[done:at])
                done = at
            flush_side()
            if kind == MK_TRIGGER:  # a timestamp reset: alone, after everything before it (as libcaer commits it)
                out.append(TriggerBatch(np.array([(t, aux)], TRIGGER_DTYPE)))
                self.triggers += 1
            elif kind == MK_EXPOSURE_START:
                out.append(ExposureMarker(int(t), "start"))
            elif kind == MK_EXPOSURE_END:
                out.append(ExposureMarker(int(t), "end"))
            else:
                es, ee = int(self.st[S_F_ES]), int(self.st[S_F_EE])
                cyc = int(self.st[S_F_CYC])
                self.last_frame_exposure_cycles = cyc
                self.frame_cycles[self.frames] = cyc
                self.frame_cycles.pop(self.frames - 64, None)
                out.append(Frame(self._image(), es, ee, 1.0, self.frames))
                self.frames += 1
        if done < ev.size:
            out.append(ev[done:])
        flush_side()
