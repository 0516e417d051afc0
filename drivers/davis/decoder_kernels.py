"""The DAVIS word-stream state machine: :func:`decode_words` (Numba) turns 16-bit words into events,
exposure and frame markers, frame pixels, IMU samples and triggers; with its state layout and helpers.

Word layout: libcaer's event translator in ``src/davis_common.h`` (github.com/inivation/libcaer;
summarised in docs/davis-protocol.md). The state lives in an int64 vector (``S_*`` indices) and the
device geometry in a configuration vector (``C_*``), so the caller
(:class:`~necviz.drivers.davis.decoder.DavisDecoder`) can resume a stream split at any byte; it turns
the kernel's outputs (``MK_*`` marker records) into packets, and its docstring states the packet and
exposure-marker rules this kernel implements.

State machine (one step per word, O(1) each, so a buffer of ``n`` words costs O(n) plus one copy per
completed frame):

* **time** — ``bit15 = 1``: ``now = wrap + (w & 0x7FFF)``; a value below ``now`` (time running
  backwards without a wrap/reset) is garbage: skipped and counted in ``time_regressions``.
  Code 7 (wrap): ``wrap += 0x8000 * data`` (``data = 0`` is garbage), ``now = wrap``.
  Special 1 (timestamp reset): ``wrap = now = 0`` and the output offset grows by the device time
  reached, so output ``t = offset + now`` (int64 µs) never decreases, across wraps and resets.
* **DVS** — code 1 stores the row (``last_y``); codes 2/3 emit one event (OFF → p = -1, ON → p = +1)
  at ``(x, last_y)`` stamped with the current time. With ``invertXY`` the row word carries x.
  An out-of-range address, a reserved/unknown special code or an X word with no valid row is
  garbage: it is skipped, and the row is forgotten so no event is emitted until the next row word
  (resynchronisation). Every event therefore corresponds to exactly one X word of the input.
* **APS** (libcaer's ``apsInitFrame``/``apsUpdateFrame``/``apsEndFrame``) — APS words are ignored until a
  frame start (special 8/9; also after a timestamp reset). ROI words (misc8 sub 1 high byte, sub 2 low
  byte: start col, start row, end col, end row, counted from the frame start) may come anywhere, before
  or after the frame start; the fourth sets the expected column/row counts, which stay until the next
  complete ROI. The exposure value (three misc10 chunks, LSB first, ADC cycles) may come after the frame
  start or before it (since the previous frame's end). Readout: special 11/12 starts a reset/signal
  column (separate counters per type), code 4 stores one sample at ``(countX[type], countY[type]++)``,
  special 13 ends the column (``countX[type]++``) → special 10 frame end: the frame is complete when both
  readouts covered every column; otherwise it is dropped (``frames_dropped``). Samples beyond the ROI,
  outside a frame or before a valid ROI are skipped. Pixel placement: ``x = flipX ? W-1-countX : countX``,
  ``y = flipY ? H-1-countY : countY``, swapped if ``invertXY`` (APS orientation bits 2..0); the image
  origin is top-left. CDS at the signal sample: ``Z10 = 1023`` if ``reset < 384`` or ``signal == 0``
  (saturated), else ``clip(reset - signal, 0, 1023)``; the frame buffer stores ``Z10`` (uint16; the
  decoder makes the 8-bit image from it, demosaicing a colour sensor's).
* **Exposure** — special 14/15 mark the exposure's start and end (markers). libcaer does not need them;
  necviz does, to announce the exposure in stream order. A complete frame without a special 14 tells
  the decoder that the logic sends none: it is counted (``frames_without_exposure``) and from then on
  the decoder places the exposure itself, in stream order, where the readout shows it: it starts when
  the reset read is done (global shutter: after the last reset column; rolling shutter: after the
  first) and ends when the signal read starts. A special 14 switches this off again.
* **IMU** — special 5 opens a sample, misc8 sub 3 gives scales and which sensors are present,
  misc8 sub 0 delivers the 14 big-endian bytes (AX AY AZ T GX GY GZ; absent sensors are skipped),
  special 7 closes it: a complete sample is emitted at the time of the end word, scaled to g, °/s
  and °C (absent sensors are NaN), with the IMU orientation flips applied.
* **Triggers** — specials 1 (timestamp reset), 2/3/4 (external input falling/rising/pulse) and
  16/17 (generator falling/rising) become :data:`~necviz.core.imu.TRIGGER_KINDS` records.

Frames have the APS array's shape: pixels of the ROI are placed at their sensor position (ROI
registers are sensor coordinates), the rest is 0.
"""

from __future__ import annotations

import numba as nb
import numpy as np

# ---- state vector layout (int64) ------------------------------------------------------------------
S_WRAP, S_NOW, S_OFFSET, S_LAST_Y = 0, 1, 2, 3
S_NEV, S_NMK, S_NIMU, S_FRAME_READY = 4, 5, 6, 7  # outputs of the last call
S_SKIPPED, S_TIME_REG, S_FRAMES_DROPPED, S_IMU_DROPPED, S_EXPO_ABORTED = 8, 9, 10, 11, 12
S_IN_FRAME, S_ROI_OK, S_ROI_IDX, S_GS = 13, 14, 15, 16  # ROI_OK: the last complete ROI was valid
S_ROI = 17  # 17..20: start col, start row, end col, end row
S_EXPX, S_EXPY, S_SIZEX = 21, 22, 23
S_RTYPE, S_CX0, S_CY0, S_CX1, S_CY1 = 24, 25, 26, 27, 28
S_EXP_IDX, S_EXP_CYC = 29, 30
S_T_FS, S_T_ES, S_HAS_ES, S_HAS_EE, S_T_EE = 31, 32, 33, 34, 35
S_EXPO_OPEN, S_EXPO_OPEN_T = 36, 37
S_IMU_ACTIVE, S_IMU_COUNT, S_IMU_TYPE, S_IMU_ASCALE, S_IMU_GSCALE = 38, 39, 40, 41, 42
S_IMU_B = 43  # 43..56: the 14 IMU bytes
S_F_ES, S_F_EE, S_F_CYC, S_F_T_END = 57, 58, 59, 60  # the completed frame
S_ROI_TMP = 61
S_WORDS = 62
S_SYNTH = 63  # 1: the stream sends no exposure specials, the decoder places the exposure itself
S_NO_EXPOSURE = 64  # complete frames dropped for want of an exposure (the first of a stream without specials)
S_APS_CUT = 65  # 1: the rest of a frame cut by a timestamp reset is arriving (ignored, not counted as garbage)
S_SIZE = 72

# ---- configuration vector layout ----------------------------------------------------------------
C_DVS_W, C_DVS_H, C_DVS_INVERT, C_APS_W, C_APS_H, C_APS_ORIENT, C_IMU_ORIENT, C_IMU_MODEL, C_ADC_SHIFT = range(9)
C_SIZE = 9

# ---- marker kinds ---------------------------------------------------------------------------------
MK_EXPOSURE_START, MK_EXPOSURE_END, MK_FRAME, MK_IMU, MK_TRIGGER = 0, 1, 2, 3, 4

# special code -> TRIGGER_KINDS index (timestamp_reset, external_rising, external_falling,
# external_pulse, generator_rising, generator_falling)
TRIG_RESET, TRIG_RISING, TRIG_FALLING, TRIG_PULSE, TRIG_GEN_RISING, TRIG_GEN_FALLING = 0, 1, 2, 3, 4, 5


@nb.njit(cache=True, inline="always")
def _marker(mk, st, kind, t, nev, aux):
    k = st[S_NMK]
    mk[k, 0] = kind
    mk[k, 1] = t
    mk[k, 2] = nev
    mk[k, 3] = aux
    st[S_NMK] = k + 1


@nb.njit(cache=True)
def _end_exposure(mk, st, t, nev, aux):
    """The open exposure ends at ``t``: emit its ``end`` marker now if ``t`` is after its start;
    otherwise (same µs) the marker is due at start + 1 µs, later than events still to come at ``t``,
    so it is only noted (state 2) and emitted by :func:`_emit_pending_end` once time moves on."""
    if t > st[S_EXPO_OPEN_T]:
        _marker(mk, st, MK_EXPOSURE_END, t, nev, aux)
        st[S_EXPO_OPEN] = 0
    else:
        st[S_EXPO_OPEN] = 2
    return st[S_EXPO_OPEN_T] + 1 if t <= st[S_EXPO_OPEN_T] else t


@nb.njit(cache=True)
def _emit_pending_end(mk, st, tnew, nev):
    """Time moves to ``tnew``: emit a pending ``end`` marker (at start + 1 <= tnew). False if ``mk`` is full."""
    if st[S_EXPO_OPEN] == 2 and tnew > st[S_EXPO_OPEN_T]:
        if st[S_NMK] >= mk.shape[0]:
            return False
        _marker(mk, st, MK_EXPOSURE_END, st[S_EXPO_OPEN_T] + 1, nev, 0)
        st[S_EXPO_OPEN] = 0
    return True


@nb.njit(cache=True)
def _close_exposure(mk, st, t, nev):
    """End an exposure left open (new frame start or timestamp reset); counted as aborted."""
    if st[S_EXPO_OPEN] == 1:
        _end_exposure(mk, st, t, nev, 1)
        st[S_EXPO_ABORTED] += 1


@nb.njit(cache=True)
def _start_exposure(mk, st, t, nev):
    """The frame's exposure starts at ``t`` (special 14, or placed by the decoder): emit its ``start`` marker."""
    st[S_HAS_ES] = 1
    st[S_T_ES] = t
    st[S_EXPO_OPEN] = 1
    st[S_EXPO_OPEN_T] = t
    _marker(mk, st, MK_EXPOSURE_START, t, nev, 0)


@nb.njit(cache=True)
def _roi_sizes(st, cfg):
    """The fourth ROI value arrived: the expected column and row counts (libcaer's apsROIUpdateSizes), or an
    invalid ROI (outside the array, end before start): no frame until a valid one."""
    c0 = st[S_ROI]
    r0 = st[S_ROI + 1]
    c1 = st[S_ROI + 2]
    r1 = st[S_ROI + 3]
    if c1 < c0 or r1 < r0 or c1 >= cfg[C_APS_W] or r1 >= cfg[C_APS_H]:
        st[S_ROI_OK] = 0
        return
    sx = c1 + 1 - c0
    sy = r1 + 1 - r0
    st[S_ROI_OK] = 1
    st[S_SIZEX] = sx
    if cfg[C_APS_ORIENT] & 4:
        st[S_EXPX] = sy
        st[S_EXPY] = sx
    else:
        st[S_EXPX] = sx
        st[S_EXPY] = sy


@nb.njit(cache=True)
def _imu_skip_absent(st):
    """Advance the IMU byte counter over sensors the config word says are absent."""
    c = st[S_IMU_COUNT]
    typ = st[S_IMU_TYPE]
    while c < 14:
        if c < 6:
            if typ & 4:
                break
            c = 6
        elif c < 8:
            if typ & 1:
                break
            c = 8
        else:
            if typ & 2:
                break
            c = 14
    st[S_IMU_COUNT] = c


@nb.njit(cache=True)
def _imu_emit(st, cfg, imu_t, imu_v, t):
    k = st[S_NIMU]
    typ = st[S_IMU_TYPE]
    a_lsb = (4 << st[S_IMU_ASCALE]) / 65536.0
    g_lsb = (500 << st[S_IMU_GSCALE]) / 65536.0
    vals = np.empty(7, np.float64)
    for j in range(7):
        raw = (st[S_IMU_B + 2 * j] << 8) | st[S_IMU_B + 2 * j + 1]
        if raw >= 32768:
            raw -= 65536
        vals[j] = raw
    nan = np.float32(np.nan)
    o = cfg[C_IMU_ORIENT]
    sx = -1.0 if o & 4 else 1.0
    sy = -1.0 if o & 2 else 1.0
    sz = -1.0 if o & 1 else 1.0
    imu_t[k] = t
    if typ & 4:
        imu_v[k, 0] = sx * vals[0] * a_lsb
        imu_v[k, 1] = sy * vals[1] * a_lsb
        imu_v[k, 2] = sz * vals[2] * a_lsb
    else:
        imu_v[k, 0] = nan
        imu_v[k, 1] = nan
        imu_v[k, 2] = nan
    if typ & 2:
        imu_v[k, 3] = sx * vals[4] * g_lsb
        imu_v[k, 4] = sy * vals[5] * g_lsb
        imu_v[k, 5] = sz * vals[6] * g_lsb
    else:
        imu_v[k, 3] = nan
        imu_v[k, 4] = nan
        imu_v[k, 5] = nan
    if typ & 1:
        if cfg[C_IMU_MODEL] == 2:
            imu_v[k, 6] = vals[3] / 333.87 + 21.0
        else:
            imu_v[k, 6] = vals[3] / 340.0 + 35.0
    else:
        imu_v[k, 6] = nan
    st[S_NIMU] = k + 1
    return k


@nb.njit(cache=True)
def _aps_run(words, i, st, cfg, reset_buf, frame):
    """Store the run of ADC samples (code 4) starting at ``words[i]``; return (next index, skipped).

    Samples go to ``(countX[type], countY[type]++)`` of the current readout type; samples outside a
    valid frame, before the ROI is known or beyond the ROI are skipped. Within a column the pixel
    index is affine in ``countY`` (``base + step * countY``, from the flips), so a sample costs a
    load, two compares and a store.
    """
    n = words.shape[0]
    typ = st[S_RTYPE]
    skipped = 0
    if st[S_IN_FRAME] == 0 or st[S_ROI_OK] == 0 or typ < 0:
        cut = st[S_IN_FRAME] == 0 and st[S_APS_CUT] == 1  # the rest of a frame cut by a reset: ignored
        while i < n and (words[i] >> 12) == 4:
            i += 1
            if not cut:
                skipped += 1
        return i, skipped
    cx = st[S_CX0] if typ == 0 else st[S_CX1]
    cy = st[S_CY0] if typ == 0 else st[S_CY1]
    ex = st[S_EXPX]
    ey = st[S_EXPY]
    o = cfg[C_APS_ORIENT]
    shift = cfg[C_ADC_SHIFT]
    sizex = st[S_SIZEX]
    fw = cfg[C_APS_W]
    fb0 = st[S_ROI + 1] * fw + st[S_ROI]  # frame index of the ROI's top-left pixel
    xc = ex - 1 - cx if o & 2 else cx  # the column coordinate is fixed within a column
    # pixel of countY = c: ROI index rb + rs * c, frame index fb + fs * c
    if o & 4:  # invertXY: countY runs along image x, countX along image y
        if o & 1:
            rb, rs, fb, fs = xc * sizex + ey - 1, -1, fb0 + xc * fw + ey - 1, -1
        else:
            rb, rs, fb, fs = xc * sizex, 1, fb0 + xc * fw, 1
    else:
        if o & 1:
            rb, rs, fb, fs = (ey - 1) * sizex + xc, -sizex, fb0 + (ey - 1) * fw + xc, -fw
        else:
            rb, rs, fb, fs = xc, sizex, fb0 + xc, fw
    valid_col = cx < ex
    while i < n:
        w = np.int64(words[i])
        if (w >> 12) != 4:
            break
        i += 1
        if not valid_col or cy >= ey:
            skipped += 1
            continue
        v = (w & 0xFFF) << shift
        if typ == 0:
            reset_buf[rb + rs * cy] = v
        else:
            r = reset_buf[rb + rs * cy]
            if r < 384 or v == 0:
                z = 1023
            else:
                z = r - v
                if z < 0:
                    z = 0
                elif z > 1023:
                    z = 1023
            frame[fb + fs * cy] = z
        cy += 1
    if typ == 0:
        st[S_CY0] = cy
    else:
        st[S_CY1] = cy
    return i, skipped


@nb.njit(cache=True, nogil=True)  # releases the GIL: the USB reader thread runs while a transfer decodes
def decode_words(words, start, st, cfg, ev, mk, imu_t, imu_v, reset_buf, frame):
    """Decode ``words[start:]`` into the output arrays; return the index after the last word used.

    ``st`` (int64[S_SIZE]) is the persistent state, ``cfg`` (int64[C_SIZE]) the device geometry and
    orientation. Outputs: ``ev`` (EVENT_DTYPE), ``mk`` (int64[m, 4]: kind, t µs, number of events
    before it, aux; m >= 2), ``imu_t``/``imu_v`` (IMU samples), ``frame`` (uint16 H x W, the 10-bit CDS values: the frame
    being assembled, flat H*W). Counts of this call are in ``st[S_NEV]``, ``st[S_NMK]``, ``st[S_NIMU]``.
    Decoding stops early when an output array is full, or right after a completed frame
    (``st[S_FRAME_READY] = 1``; its times in ``st[S_F_ES]``/``st[S_F_EE]``) so the caller can copy
    it; the caller resumes at the returned index. O(n) in the number of words.
    """
    n = words.shape[0]
    wrap = st[S_WRAP]
    now = st[S_NOW]
    offset = st[S_OFFSET]
    last_y = st[S_LAST_Y]
    nev = 0
    st[S_NMK] = 0
    st[S_NIMU] = 0
    st[S_FRAME_READY] = 0
    skipped = 0
    dvs_w = cfg[C_DVS_W]
    dvs_h = cfg[C_DVS_H]
    inv = cfg[C_DVS_INVERT]
    row_lim = dvs_w if inv else dvs_h
    col_lim = dvs_h if inv else dvs_w
    tcur = offset + now
    mk_cap = mk.shape[0]
    imu_cap = imu_t.shape[0]
    # every event needs at least one word: stopping after ev.shape[0] words can never overflow ``ev``
    stop = min(n, start + ev.shape[0])
    i = start
    while i < stop:
        w = np.int64(words[i])
        i += 1
        if w & 0x8000:
            t = wrap + (w & 0x7FFF)
            if t >= now:
                if not _emit_pending_end(mk, st, offset + t, nev):
                    i -= 1
                    break
                now = t
                tcur = offset + now
            else:
                skipped += 1
                st[S_TIME_REG] += 1
            continue
        code = w >> 12
        data = w & 0xFFF
        if code == 2 or code == 3:
            if last_y >= 0 and data < col_lim:
                e = ev[nev]
                e.t = tcur
                if inv:
                    e.x = last_y
                    e.y = data
                else:
                    e.x = data
                    e.y = last_y
                e.p = 1 if code == 3 else -1
                nev += 1
            else:
                skipped += 1
                last_y = -1
            continue
        if code == 1:
            if data < row_lim:
                last_y = data
            else:
                skipped += 1
                last_y = -1
            continue
        if code == 4:
            i, sk = _aps_run(words, i - 1, st, cfg, reset_buf, frame)
            skipped += sk
            continue
        if code == 7:
            if data == 0:
                skipped += 1
                last_y = -1
            else:
                if not _emit_pending_end(mk, st, offset + wrap + 0x8000 * data, nev):
                    i -= 1
                    break
                wrap += 0x8000 * data
                now = wrap
                tcur = offset + now
            continue
        if code == 5:
            sub = (data >> 8) & 0xF
            v = data & 0xFF
            if sub == 0:  # IMU data byte
                if st[S_IMU_ACTIVE] == 1:
                    _imu_skip_absent(st)
                    c = st[S_IMU_COUNT]
                    if c < 14:
                        st[S_IMU_B + c] = v
                        st[S_IMU_COUNT] = c + 1
                    else:
                        skipped += 1
                        st[S_IMU_ACTIVE] = 2  # overfull: the sample is dropped at its end word
                elif st[S_IMU_ACTIVE] != 3:  # 3: the rest of a sample cut by a reset, ignored
                    skipped += 1
            elif sub == 1:  # ROI value, high byte (kept for the low byte, libcaer's roi.tmpData)
                st[S_ROI_TMP] = v << 8
            elif sub == 2:  # ROI value, low byte: start col, start row, end col, end row in turn
                r = st[S_ROI_IDX] & 3
                st[S_ROI + r] = st[S_ROI_TMP] | v
                st[S_ROI_IDX] = r + 1
                if r == 3:
                    _roi_sizes(st, cfg)
            elif sub == 3:  # IMU configuration
                if st[S_IMU_ACTIVE] == 1 and st[S_IMU_COUNT] == 0:
                    st[S_IMU_ASCALE] = (v >> 2) & 3
                    st[S_IMU_GSCALE] = v & 3
                    st[S_IMU_TYPE] = (v >> 5) & 7
                elif st[S_IMU_ACTIVE] != 3:
                    skipped += 1
            else:
                skipped += 1
            continue
        if code == 6:  # exposure value chunks: before or after the frame start (see the frame-start case)
            sub = (data >> 10) & 3
            if sub == 0 and st[S_EXP_IDX] < 3:
                st[S_EXP_CYC] |= (data & 0x3FF) << (10 * st[S_EXP_IDX])
                st[S_EXP_IDX] += 1
            else:
                skipped += 1
            continue
        # code 0: special events (each emits at most 2 markers and 1 IMU sample)
        if st[S_NMK] + 2 > mk_cap or st[S_NIMU] >= imu_cap:
            i -= 1
            break
        if data == 13:  # column end
            if st[S_IN_FRAME] == 1 and st[S_RTYPE] >= 0:
                if st[S_RTYPE] == 0:
                    st[S_CX0] += 1
                    # no exposure specials in this stream: the exposure starts when the reset read is done
                    # (global shutter: all columns; rolling shutter: the first column)
                    if (
                        st[S_SYNTH] == 1
                        and st[S_HAS_ES] == 0
                        and st[S_EXPO_OPEN] == 0
                        and (st[S_CX0] == st[S_EXPX] or st[S_GS] == 0)
                    ):
                        _start_exposure(mk, st, tcur, nev)
                else:
                    st[S_CX1] += 1
            elif st[S_APS_CUT] == 0:
                skipped += 1
        elif data == 11 or data == 12:  # reset / signal column start
            if st[S_IN_FRAME] == 1:
                if data == 11:
                    st[S_RTYPE] = 0
                    st[S_CY0] = 0
                else:
                    st[S_RTYPE] = 1
                    st[S_CY1] = 0
                    # no exposure specials: the exposure ends when the signal read starts
                    if st[S_SYNTH] == 1 and st[S_EXPO_OPEN] == 1 and st[S_HAS_EE] == 0:
                        st[S_T_EE] = _end_exposure(mk, st, tcur, nev, 0)
                        st[S_HAS_EE] = 1
            elif st[S_APS_CUT] == 0:
                skipped += 1
        elif data == 8 or data == 9:  # frame start (libcaer's apsInitFrame; the ROI is kept)
            _close_exposure(mk, st, tcur, nev)
            if st[S_IN_FRAME] == 1:
                st[S_FRAMES_DROPPED] += 1
            st[S_IN_FRAME] = 1
            st[S_APS_CUT] = 0
            st[S_GS] = 1 if data == 8 else 0
            st[S_ROI_IDX] = 0
            st[S_ROI_TMP] = 0
            st[S_RTYPE] = -1
            st[S_CX0] = 0
            st[S_CY0] = 0
            st[S_CX1] = 0
            st[S_CY1] = 0
            if st[S_EXP_IDX] != 3:  # a complete value sent before this start (since the last frame) is this frame's
                st[S_EXP_IDX] = 0
                st[S_EXP_CYC] = 0
            st[S_T_FS] = tcur
            st[S_HAS_ES] = 0
            st[S_HAS_EE] = 0
            frame[:] = 0
        elif data == 14:  # exposure start
            st[S_SYNTH] = 0  # this stream sends exposure specials
            if st[S_IN_FRAME] == 1 and st[S_HAS_ES] == 0 and st[S_EXPO_OPEN] == 0:
                _start_exposure(mk, st, tcur, nev)
            elif st[S_APS_CUT] == 0:
                skipped += 1
        elif data == 15:  # exposure end
            if st[S_EXPO_OPEN] == 1:
                st[S_T_EE] = _end_exposure(mk, st, tcur, nev, 0)
                st[S_HAS_EE] = 1
            elif st[S_APS_CUT] == 0:
                skipped += 1
        elif data == 10:  # frame end: complete when both readouts covered every column (libcaer's apsEndFrame)
            if st[S_IN_FRAME] == 1:
                ex = st[S_EXPX]
                complete = st[S_ROI_OK] == 1 and st[S_CX0] == ex and st[S_CX1] == ex
                # a complete frame also needs its exposure announced in stream order: a start and an end
                # marker already delivered (not still pending: an end in the µs its exposure started)
                announced = st[S_HAS_ES] == 1 and st[S_HAS_EE] == 1 and st[S_EXPO_OPEN] == 0
                st[S_IN_FRAME] = 0
                cyc = st[S_EXP_CYC] if st[S_EXP_IDX] == 3 else -1
                st[S_EXP_IDX] = 0  # the next frame's value may come before its start
                st[S_EXP_CYC] = 0
                if complete and announced:
                    st[S_F_ES] = st[S_T_ES]
                    st[S_F_EE] = st[S_T_EE]
                    st[S_F_CYC] = cyc
                    st[S_F_T_END] = tcur
                    _marker(mk, st, MK_FRAME, tcur, nev, 0)
                    st[S_FRAME_READY] = 1
                    break
                if complete and st[S_HAS_ES] == 0:
                    # no exposure start special in a complete frame: the logic sends none, so from the next
                    # frame on the decoder places the exposure itself (this one cannot be announced any more)
                    st[S_SYNTH] = 1
                    st[S_NO_EXPOSURE] += 1
                else:
                    st[S_FRAMES_DROPPED] += 1
            elif st[S_APS_CUT] == 1:  # the end of a frame cut by a reset: it was counted as dropped then
                st[S_APS_CUT] = 0
            else:
                skipped += 1
        elif data == 5:  # IMU sample start
            if st[S_IMU_ACTIVE] == 1 or st[S_IMU_ACTIVE] == 2:
                st[S_IMU_DROPPED] += 1
            st[S_IMU_ACTIVE] = 1
            st[S_IMU_COUNT] = 0
            st[S_IMU_TYPE] = 7
            st[S_IMU_ASCALE] = 0
            st[S_IMU_GSCALE] = 0
        elif data == 7:  # IMU sample end
            if st[S_IMU_ACTIVE] == 1:
                _imu_skip_absent(st)
                if st[S_IMU_COUNT] == 14:
                    k = _imu_emit(st, cfg, imu_t, imu_v, tcur)
                    _marker(mk, st, MK_IMU, tcur, nev, k)
                else:
                    st[S_IMU_DROPPED] += 1
            elif st[S_IMU_ACTIVE] == 2:
                st[S_IMU_DROPPED] += 1
            elif st[S_IMU_ACTIVE] != 3:
                skipped += 1
            st[S_IMU_ACTIVE] = 0
        elif data == 1:  # timestamp reset
            _close_exposure(mk, st, tcur, nev)
            offset = tcur
            wrap = 0
            now = 0
            _marker(mk, st, MK_TRIGGER, tcur, nev, TRIG_RESET)
            # the frame and the IMU sample in progress are dropped; their remaining words are ignored until the
            # next start (libcaer's ignoreEvents), without counting them as garbage
            if st[S_IN_FRAME] == 1:
                st[S_FRAMES_DROPPED] += 1
                st[S_APS_CUT] = 1
            st[S_IN_FRAME] = 0
            st[S_EXP_IDX] = 0
            st[S_EXP_CYC] = 0
            if st[S_IMU_ACTIVE] == 1 or st[S_IMU_ACTIVE] == 2:
                st[S_IMU_DROPPED] += 1
                st[S_IMU_ACTIVE] = 3
            else:
                st[S_IMU_ACTIVE] = 0
        elif data == 2:
            _marker(mk, st, MK_TRIGGER, tcur, nev, TRIG_FALLING)
        elif data == 3:
            _marker(mk, st, MK_TRIGGER, tcur, nev, TRIG_RISING)
        elif data == 4:
            _marker(mk, st, MK_TRIGGER, tcur, nev, TRIG_PULSE)
        elif data == 16:
            _marker(mk, st, MK_TRIGGER, tcur, nev, TRIG_GEN_FALLING)
        elif data == 17:
            _marker(mk, st, MK_TRIGGER, tcur, nev, TRIG_GEN_RISING)
        else:  # reserved (0) or unknown special code: garbage
            skipped += 1
            last_y = -1
    st[S_WRAP] = wrap
    st[S_NOW] = now
    st[S_OFFSET] = offset
    st[S_LAST_Y] = last_y
    st[S_NEV] = nev
    st[S_SKIPPED] += skipped
    st[S_WORDS] += i - start
    return i
