"""Events, frames, IMU samples and triggers → the DAVIS 16-bit word stream (logic 18).

Written from the documented layout (docs/davis-protocol.md, after libcaer's ``src/davis_common.h``), not
from the decoder, so encoder→decoder round trips check the decoder against an independent reading of the
format. Used by the emulator (:mod:`.emulator`), the tests and ``necviz bench decode``.

:class:`StreamEncoder` keeps the device-side state (current timestamp, wrap base, last row) and
returns ``uint16`` word arrays; times are device microseconds and must not decrease. Each
timestamp that differs from the current one costs wrap words (code 7, up to 4095 wraps each) and a
timestamp word (``0x8000 | t & 0x7FFF``); each event costs an X word plus a Y word when its row
differs from the previous event's. Events are encoded by a Numba kernel (two passes: count, fill).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError

#: special event codes (code 0)
TS_RESET, EXT_FALLING, EXT_RISING, EXT_PULSE = 1, 2, 3, 4
IMU_START, IMU_END = 5, 7
FRAME_START_GS, FRAME_START_RS, FRAME_END = 8, 9, 10
RESET_COL_START, SIGNAL_COL_START, COL_END = 11, 12, 13
EXPOSURE_START, EXPOSURE_END = 14, 15
GEN_FALLING, GEN_RISING = 16, 17

#: TRIGGER_KINDS name -> special code
TRIGGER_CODES = {
    "timestamp_reset": TS_RESET,
    "external_rising": EXT_RISING,
    "external_falling": EXT_FALLING,
    "external_pulse": EXT_PULSE,
    "generator_rising": GEN_RISING,
    "generator_falling": GEN_FALLING,
}


@nb.njit(cache=True)
def _time_words(t, wrap, now, out, k):
    """Write the wrap/timestamp words moving the device clock from (wrap, now) to ``t``."""
    if t != now:
        nwraps = (t >> 15) - (wrap >> 15)
        while nwraps > 0:
            step = min(nwraps, 4095)
            out[k] = 0x7000 | step
            k += 1
            nwraps -= step
        out[k] = 0x8000 | (t & 0x7FFF)
        k += 1
    return k


@nb.njit(cache=True)
def _encode_events(t, x, y, p, state, out, always_y):
    """Encode events; ``state`` = [wrap, now, last_y]; ``out=None`` only counts. Returns words used."""
    wrap = state[0]
    now = state[1]
    last_y = state[2]
    k = 0
    for i in range(t.shape[0]):
        ti = t[i]
        if ti != now:
            nwraps = (ti >> 15) - (wrap >> 15)
            while nwraps > 0:
                step = min(nwraps, 4095)
                if out is not None:
                    out[k] = 0x7000 | step
                k += 1
                nwraps -= step
            if out is not None:
                out[k] = 0x8000 | (ti & 0x7FFF)
            k += 1
            wrap = ti & ~np.int64(0x7FFF)
            now = ti
        yi = np.int64(y[i])
        if always_y or yi != last_y:
            if out is not None:
                out[k] = 0x1000 | yi
            k += 1
            last_y = yi
        if out is not None:
            out[k] = (0x3000 if p[i] > 0 else 0x2000) | np.int64(x[i])
        k += 1
    if out is not None:
        state[0] = wrap
        state[1] = now
        state[2] = last_y
    return k


def _u16(seq) -> np.ndarray:
    return np.asarray(seq, dtype=np.uint16)


#: :attr:`StreamLayout.header` values
HEADER_LAYOUTS = ("after", "before")


@dataclass(frozen=True)
class StreamLayout:
    """Where a camera's logic puts the frame words libcaer does not need in a fixed place.

    Parameters
    ----------
    header : str
        ``"after"``: frame start (special 8/9), then the exposure value (three misc10 chunks) and the ROI
        (eight misc8 words), the order of the FPGA source; ``"before"``: the exposure value and the ROI
        first, then the frame start, as an older port of the APS state machine sends them.
    exposure_specials : bool
        Send the APS exposure start/end specials (14, 15). libcaer accepts frames without them.

    Raises
    ------
    ParameterError
        An unknown ``header``.
    """

    header: str = "after"
    exposure_specials: bool = True

    def __post_init__(self) -> None:
        if self.header not in HEADER_LAYOUTS:
            raise ParameterError(f"stream header layout must be one of {HEADER_LAYOUTS}, got {self.header!r}")
        object.__setattr__(self, "exposure_specials", bool(self.exposure_specials))


@dataclass(frozen=True)
class FrameTiming:
    """The four times of one encoded frame (device µs): frame start, exposure start and end, frame end.

    Parameters
    ----------
    start_us, exposure_start_us, exposure_end_us, end_us : int
        Non-negative whole microseconds, in this order (equal times allowed).

    Raises
    ------
    ParameterError
        A time that is not a whole number >= 0, or times out of order.
    """

    start_us: int
    exposure_start_us: int
    exposure_end_us: int
    end_us: int

    def __post_init__(self) -> None:
        times = []
        for name in ("start_us", "exposure_start_us", "exposure_end_us", "end_us"):
            times.append(check_number(name, getattr(self, name), 0, integer=True, where="frame timing"))
            object.__setattr__(self, name, times[-1])
        if times != sorted(times):
            raise ParameterError(f"frame timing must not go back in time: {tuple(times)} µs")


class StreamEncoder:
    """Stateful encoder of a DAVIS word stream (device time in µs, non-decreasing).

    ``aps_orientation`` (bit2 invertXY, bit1 flipX, bit0 flipY) sets the readout order of frame
    samples so that a decoder applying the same bits puts every pixel back where it was.
    ``always_y``: repeat the row word before every X word (a valid, less compact stream).
    ``dvs_invert_xy``: DVS orientation bit 2 (the row word carries x and the column word y, libcaer's
    ``dvs.invertXY``). ``layout``: where the frame header words go and whether exposure specials are sent
    (:class:`StreamLayout`).
    """

    def __init__(
        self,
        aps_orientation: int = 0,
        always_y: bool = False,
        *,
        dvs_invert_xy: bool = False,
        layout: StreamLayout | None = None,
    ):
        self.aps_orientation = int(aps_orientation) & 7
        self.always_y = bool(always_y)
        self.dvs_invert_xy = bool(dvs_invert_xy)
        self.layout = StreamLayout() if layout is None else layout
        self.state = np.array([0, 0, -1], np.int64)  # wrap base, current time, last row

    @property
    def now_us(self) -> int:
        return int(self.state[1])

    # -- time -------------------------------------------------------------------------------------
    def time(self, t_us: int) -> np.ndarray:
        """Words that move the device clock to ``t_us`` (empty if it is already there)."""
        t_us = int(t_us)
        wrap, now = int(self.state[0]), int(self.state[1])
        if t_us < now:
            raise ParameterError(f"encoder time must not decrease: {t_us} µs after {now} µs")
        out = np.zeros(((t_us >> 15) - (wrap >> 15)) // 4095 + 2, np.uint16)
        k = _time_words(t_us, wrap, now, out, 0)
        self.state[0] = t_us & ~0x7FFF
        self.state[1] = t_us
        return out[:k]

    def timestamp_reset(self) -> np.ndarray:
        """The device's timestamp reset (special 1): the clock restarts at 0."""
        self.state[:] = (0, 0, self.state[2])
        return _u16([TS_RESET])

    def special(self, t_us: int, code: int) -> np.ndarray:
        return np.concatenate([self.time(t_us), _u16([code])])

    def trigger(self, t_us: int, kind: str) -> np.ndarray:
        """An external-input / generator trigger (``TRIGGER_KINDS`` name, not timestamp_reset)."""
        if kind not in TRIGGER_CODES or kind == "timestamp_reset":
            raise ParameterError(f"cannot encode trigger kind {kind!r}")
        return self.special(t_us, TRIGGER_CODES[kind])

    # -- events -----------------------------------------------------------------------------------
    def events(self, ev: np.ndarray) -> np.ndarray:
        """Encode an EVENT_DTYPE batch (time-sorted, t >= the current time)."""
        if ev.size == 0:
            return np.zeros(0, np.uint16)
        t = np.ascontiguousarray(ev["t"], dtype=np.int64)
        if int(t[0]) < self.now_us or (t.size > 1 and np.any(t[1:] < t[:-1])):
            raise ParameterError("events to encode must be time-sorted and not earlier than the encoder's time")
        x, y, p = (np.ascontiguousarray(ev[f]) for f in ("x", "y", "p"))
        if self.dvs_invert_xy:  # the row word carries x
            x, y = y, x
        if int(x.max()) > 0xFFF or int(y.max()) > 0xFFF:
            raise ParameterError("event addresses must fit in 12 bits")
        n = _encode_events(t, x, y, p, self.state.copy(), None, self.always_y)
        out = np.empty(n, np.uint16)
        _encode_events(t, x, y, p, self.state, out, self.always_y)
        return out

    # -- frames -----------------------------------------------------------------------------------
    def frame_start(
        self, t_us: int, roi: tuple[int, int, int, int], exposure_cycles: int | None = None, global_shutter: bool = True
    ) -> np.ndarray:
        """Frame start (special 8 GS / 9 RS), optional exposure chunks, 8 ROI words (c0, r0, c1, r1); the
        chunks and the ROI words follow the start, or precede it (``layout.header == "before"``)."""
        header = []
        if exposure_cycles is not None:
            c = int(exposure_cycles)
            header += [0x6000 | (c >> (10 * j)) & 0x3FF for j in range(3)]
        for v in roi:
            header += [0x5100 | (int(v) >> 8) & 0xFF, 0x5200 | int(v) & 0xFF]
        start = [FRAME_START_GS if global_shutter else FRAME_START_RS]
        words = header + start if self.layout.header == "before" else start + header
        return np.concatenate([self.time(t_us), _u16(words)])

    def exposure_special(self, t_us: int, start: bool) -> np.ndarray:
        """Exposure start (special 14) or end (15) at ``t_us``; nothing if the layout sends no exposure specials."""
        if not self.layout.exposure_specials:
            return np.zeros(0, np.uint16)
        return self.special(t_us, EXPOSURE_START if start else EXPOSURE_END)

    def signal_start(self, t_us: int) -> np.ndarray:
        """The first signal-read column starts at ``t_us`` (when the exposure ends); the rest of the signal read
        follows with :meth:`readout` ``(..., signal=True, first_started=True)``."""
        return self.special(t_us, SIGNAL_COL_START)

    def readout_order(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the ROI image in readout order: ``[countX, countY]`` → pixel."""
        o = self.aps_orientation
        ex, ey = (h, w) if o & 4 else (w, h)
        cx, cy = np.meshgrid(np.arange(ex), np.arange(ey), indexing="ij")
        x = ex - 1 - cx if o & 2 else cx
        y = ey - 1 - cy if o & 1 else cy
        if o & 4:
            x, y = y, x
        return y, x  # shapes (ex, ey)

    def readout(self, values: np.ndarray, signal: bool, first_started: bool = False) -> np.ndarray:
        """All columns of one readout (reset or signal) of a ROI image of 10-bit values (h x w);
        ``first_started``: the first column's start word was already sent (:meth:`signal_start`)."""
        v = np.asarray(values)
        if v.ndim != 2 or (v.size and (v.min() < 0 or v.max() > 0xFFF)):
            raise ParameterError("readout values must be a 2-D array of 12-bit ADC samples")
        rows, cols = self.readout_order(*v.shape)
        ex, ey = rows.shape
        block = np.empty((ex, ey + 2), np.uint16)
        block[:, 0] = SIGNAL_COL_START if signal else RESET_COL_START
        block[:, 1:-1] = 0x4000 | v[rows, cols].astype(np.uint16)
        block[:, -1] = COL_END
        return block.ravel()[1:] if first_started else block.ravel()

    def frame(
        self,
        timing: FrameTiming,
        reset: np.ndarray,
        signal: np.ndarray,
        roi: tuple[int, int, int, int] | None = None,
        exposure_cycles: int | None = None,
        global_shutter: bool = True,
    ) -> np.ndarray:
        """A whole frame with no events inside (GS order: start, reset read, exposure, signal read, end; the
        header and the exposure specials as ``layout`` says).

        Parameters
        ----------
        timing : FrameTiming
            When the frame starts, its exposure starts and ends, and the frame ends (device µs).
        reset, signal : numpy.ndarray
            The reset and signal reads of the ROI image (h x w ADC samples; :func:`cds_pair`).
        roi : tuple of int, optional
            ``(c0, r0, c1, r1)`` (default: the whole image).
        exposure_cycles : int, optional
            The exposure the frame reports (ADC cycles; default: none).
        global_shutter : bool
            Frame start special 8 (global shutter) or 9 (rolling shutter).

        Raises
        ------
        ParameterError
            ``timing`` before the encoder's time, or samples that are not 12-bit.
        """
        if not isinstance(timing, FrameTiming):
            raise ParameterError(f"frame timing must be a FrameTiming, got {type(timing).__name__}")
        h, w = np.shape(reset)
        roi = roi or (0, 0, w - 1, h - 1)
        return np.concatenate(
            [
                self.frame_start(timing.start_us, roi, exposure_cycles, global_shutter),
                self.time(timing.exposure_start_us),  # the reset read ends as the exposure starts
                self.readout(reset, False),
                self.exposure_special(timing.exposure_start_us, True),
                self.exposure_special(timing.exposure_end_us, False),
                self.signal_start(timing.exposure_end_us),  # and the signal read starts as it ends
                self.readout(signal, True, first_started=True),
                self.special(timing.end_us, FRAME_END),
            ]
        )

    # -- IMU --------------------------------------------------------------------------------------
    def imu(self, t_us: int, raw, accel_scale: int = 1, gyro_scale: int = 1, sensors: int = 7) -> np.ndarray:
        """One IMU sample: ``raw`` = 7 int16 (AX AY AZ T GX GY GZ); ``sensors`` bit2 accel, bit1 gyro,
        bit0 temperature (absent sensors send no bytes)."""
        raw = np.asarray(raw, np.int64)
        cfg = (sensors & 7) << 5 | (accel_scale & 3) << 2 | (gyro_scale & 3)
        words = [IMU_START, 0x5300 | cfg]
        for j, present in ((0, 4), (1, 4), (2, 4), (3, 1), (4, 2), (5, 2), (6, 2)):
            if sensors & present:
                v = int(raw[j]) & 0xFFFF
                words += [0x5000 | v >> 8, 0x5000 | v & 0xFF]
        words.append(IMU_END)
        return np.concatenate([self.time(t_us), _u16(words)])


def cds_pair(z8: np.ndarray, reset_level: int = 1023, adc_shift: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Reset and signal samples whose CDS decodes to ``z8``: ``reset - signal = (4 Z8 + 1) >> adc_shift``.

    ``adc_shift`` is the decoder's left shift of the samples (1 on a DAVIS240, whose samples libcaer
    doubles), so the decoded 10-bit value is ``4 Z8 + 1`` or ``4 Z8`` and ``>> 2`` gives ``Z8`` back. With
    ``reset_level`` >= 1021 every Z8 in 0..255 gives a signal >= 1, so no sample reads as saturated.
    """
    z = np.asarray(z8, np.int64)
    reset = np.full(z.shape, int(reset_level), np.int64)
    return reset, reset - ((4 * z + 1) >> int(adc_shift))
