"""AEDAT 2.0 (jAER) replay for DAVIS cameras: DVS events, APS frames rebuilt from samples, IMU.

Layout: ASCII header lines starting with ``#`` (``#!AER-DAT2.0``, ``# AEChip: ...Davis346B`` names
the sensor), then 8-byte records: big-endian ``uint32 address``, ``int32 timestamp`` (µs; int32
wrap-around is unwrapped). Address words (jAER coordinates ``x'``, ``y'`` have their origin at the
lower-left and are flipped to image coordinates ``x = W-1-x'``, ``y = H-1-y'``):

* DVS: bit 31 = 0, bit 10 = 0; polarity bit 11 (1 = ON); ``x'`` bits 12-21; ``y'`` bits 22-30.
* APS sample: bit 31 = 1, bits 10-11 = readout (0 reset, 1 signal), ADC value bits 0-9, ``x'``, ``y'``
  as for DVS.
* IMU: ``(addr & 0x80000C00) == 0x80000C00``; sample type bits 28-30 (0 ax, 1 ay, 2 az, 3 temp,
  4 gx, 5 gy, 6 gz); 16-bit signed raw value bits 12-27; 7 consecutive words form one sample.
  Converted with jAER's default full scales: accelerometer ``raw / 8192`` g (±4 g), gyroscope
  ``raw / 65.5`` °/s (±500 °/s), temperature ``raw / 340 + 35`` °C (axes as stored, not re-signed).
* External input: bit 31 = 0, bit 10 = 1, low bits = code (2 falling, 3 rising, 4 pulse) -> triggers.

Frames: APS samples are assembled per pixel (Numba): a frame starts with the first reset read and
a new one whenever a pixel is reset-read a second time; it is complete when every pixel has been
signal-read. Value = CDS ``reset - signal`` clipped to 0..1023 (10-bit), then ``>> 2`` to uint8.
Incomplete frames (at the file start/end) are dropped and counted.

Exposure is not stored in AEDAT 2.0. With ``exposure_us`` (``--exposure-us``) a frame's exposure is
``[t_signal - exposure_us, t_signal]``, ``t_signal`` being the first signal read of the frame
(exposure_source ``"user (--exposure-us)"``). Otherwise it is *estimated from frame timing* as
``[first reset read, first signal read]``: the first pixel read out is reset-read when its
integration starts and signal-read when it ends (global shutter: reset readout during exposure,
charge transfer just before the signal readout), so for that pixel this interval is the exposure
(jAER computes exposure "from frame timings" the same way). It overestimates by at most one
pixel-read time.

Bounded memory: the file is read in blocks of 1 Mi records (8 MiB). Damage: a partial trailing
record (a body that is not a multiple of 8 bytes), or a timestamp that jumps backwards by more than
2 ms (not an int32 wrap) or forwards by more than 2^30 µs, raises :class:`RecordingError` with the
byte offset after the packets before it were yielded. Seeking: blocks are located by bisection on record timestamps (monotonic files).
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterator

import numba as nb
import numpy as np

from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE
from necviz.drivers.recordings.aedat3 import read_text_header
from necviz.drivers.recordings.reader import Recording, StreamAssembler, sensor_from_chip, sensor_from_extent

MAGIC = b"#!AER-DAT2.0"
RECORD = np.dtype([("addr", ">u4"), ("ts", ">i4")])
BLOCK_RECORDS = 1 << 20
BACKWARD_TOLERANCE_US = 2_000
FORWARD_LIMIT_US = 1 << 30
ACCEL_LSB_PER_G = 8192.0
GYRO_LSB_PER_DPS = 65.5
EXT_TO_TRIGGER = {2: 2, 3: 1, 4: 3}  # jAER external input code -> TRIGGER_KINDS index


@nb.njit(cache=True)
def assemble_aps(kind, x, y, adc, ts, width, height, reset, signal, rseen, sseen, state, out_img, out_t):
    """Assemble APS samples into CDS frames; returns the number of frames completed in this call.

    ``kind`` 0 reset / 1 signal; ``x``, ``y`` image coordinates; ``adc`` 10-bit values; ``ts`` µs.
    Persistent state between calls: ``reset``/``signal`` values, ``rseen``/``sseen`` flags per pixel,
    ``state`` = [n_reset, n_signal, t_first_reset, t_first_signal, t_last_signal, incomplete,
    orphan_signals]. Completed frames go to ``out_img[k]`` (uint8) and ``out_t[k]`` = (first reset,
    first signal, last signal) µs.
    """
    npx = width * height
    nout = 0
    for i in range(kind.size):
        xi = x[i]
        yi = y[i]
        if xi < 0 or yi < 0 or xi >= width or yi >= height:
            continue
        pix = yi * width + xi
        if kind[i] == 0:
            if rseen[pix] == 1:  # second reset of this pixel: a new frame begins
                state[5] += 1
                rseen[:] = 0
                sseen[:] = 0
                state[0] = 0
                state[1] = 0
            if state[0] == 0:
                state[2] = ts[i]
            rseen[pix] = 1
            reset[pix] = adc[i]
            state[0] += 1
        elif kind[i] == 1:
            if rseen[pix] == 0:
                state[6] += 1
                continue
            if state[1] == 0:
                state[3] = ts[i]
            if sseen[pix] == 0:
                sseen[pix] = 1
                state[1] += 1
            signal[pix] = adc[i]
            state[4] = ts[i]
            if state[1] == npx:
                for j in range(npx):
                    v = reset[j] - signal[j]
                    if v < 0:
                        v = 0
                    elif v > 1023:
                        v = 1023
                    out_img[nout, j] = v >> 2
                out_t[nout, 0] = state[2]
                out_t[nout, 1] = state[3]
                out_t[nout, 2] = state[4]
                nout += 1
                rseen[:] = 0
                sseen[:] = 0
                state[0] = 0
                state[1] = 0
    return nout


class Aedat2Recording(Recording):
    """Replay a jAER AEDAT 2.0 DAVIS file (see the module docstring)."""

    format = "aedat2"

    def __init__(self, path, **kwargs):
        super().__init__(path, **kwargs)
        self.size = os.path.getsize(self.path)
        with open(self.path, "rb") as fh:
            head = fh.read(len(MAGIC))
            if head != MAGIC:
                raise self.error(f"wrong magic (expected '#!AER-DAT2.0', found {head!r})", 0)
            lines, self._data_start = read_text_header(self.path, fh, (MAGIC,), None)
            self.header_lines = lines
            chip = next((ln.partition(":")[2].strip() for ln in lines if ln.strip().startswith("AEChip")), "")
            self.properties = {"chip": chip} if chip else {}
            self.camera_name = chip.rsplit(".", 1)[-1] or None if chip else None  # jAER's class: Davis346B
            if self.sensor is None and chip:
                self.sensor = sensor_from_chip(chip.rsplit(".", 1)[-1])
            if self.sensor is None:
                fh.seek(self._data_start)
                head = fh.read(8 * BLOCK_RECORDS)
                rec = np.frombuffer(head[: len(head) // 8 * 8], RECORD)
                a = rec["addr"][(rec["addr"] & 0x80000400) == 0] if rec.size else rec["addr"]
                if a.size == 0:
                    raise self.error(
                        "cannot tell the sensor size (no AEChip header, no DVS events); pass a sensor geometry"
                    )
                self.sensor = sensor_from_extent(int(((a >> 12) & 0x3FF).max()), int(((a >> 22) & 0x1FF).max()))
        self.n_records = (self.size - self._data_start) // 8
        self._tail = (self.size - self._data_start) % 8
        self.exposure_source = "user (--exposure-us)" if self.exposure_us is not None else "estimated from frame timing"

    def _ts_at(self, fh, i: int) -> int:
        fh.seek(self._data_start + 8 * i + 4)
        return int(np.frombuffer(fh.read(4), ">i4")[0])

    def _first_record(self, fh) -> int:
        """Bisection on record timestamps for the first record at/after ``start_us`` minus 1 s of margin."""
        if self.start_us is None or self.n_records == 0:
            return 0
        target = self.start_us - 1_000_000
        lo, hi = 0, self.n_records
        while lo < hi:
            mid = (lo + hi) // 2
            if self._ts_at(fh, mid) < target:
                lo = mid + 1
            else:
                hi = mid
        return lo

    def _packets(self) -> Iterator:
        W, H = self.sensor.width, self.sensor.height
        npx = W * H
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        reset = np.zeros(npx, np.int32)
        signal = np.zeros(npx, np.int32)
        rseen = np.zeros(npx, np.uint8)
        sseen = np.zeros(npx, np.uint8)
        state = np.zeros(7, np.int64)
        counts: Counter = Counter()
        imu_carry = np.zeros(0, RECORD)
        wrap = 0
        prev_ts = None
        lag, seq = 0, 0
        self._carry_t = np.zeros(0, np.int64)
        self._asm = asm
        fh = open(self.path, "rb")
        try:
            i0 = self._first_record(fh)
            for start in range(i0, self.n_records, BLOCK_RECORDS):
                n = min(BLOCK_RECORDS, self.n_records - start)
                self._where = self._data_start + 8 * start
                fh.seek(self._where)
                data = fh.read(8 * n)
                if len(data) < 8 * n:  # the file shrank while being read
                    yield from asm.drain(None)
                    raise self.error(f"file ends early ({len(data)} of {8 * n} bytes)", self._where)
                rec = np.frombuffer(data, RECORD)
                raw = rec["ts"].astype(np.int64)
                # unwrap int32 timestamps and find damage (big jumps that are not wraps)
                prev = raw[0] if prev_ts is None else prev_ts
                d = np.diff(raw, prepend=prev)
                wraps = (d < -(1 << 31)) & (np.concatenate([[prev], raw[:-1]]) > (1 << 30)) & (raw < -(1 << 30))
                bad = ((d < -BACKWARD_TOLERANCE_US) & ~wraps) | (d > FORWARD_LIMIT_US)
                stop = int(np.flatnonzero(bad)[0]) if bad.any() else n
                t = raw + (wrap + np.cumsum(wraps)) * (1 << 32)
                wrap += int(wraps[:stop].sum())
                rec, t = rec[:stop], t[:stop]
                if stop:
                    prev_ts = int(raw[stop - 1])
                addr = rec["addr"]
                lag = self._decode(addr, t, asm, W, H, reset, signal, rseen, sseen, state, counts, lag, seq)
                seq = counts["frames"]
                imu_carry = self._imu(addr, t, asm, imu_carry, counts)
                if stop < n:
                    yield from asm.drain(None)
                    raise self.error(
                        f"timestamp jumps from {int(raw[stop - 1] if stop else prev)} to {int(raw[stop])} µs"
                        " (garbage or damaged data)",
                        self._data_start + 8 * (start + stop),
                    )
                watermark = asm.holdback_watermark(lag)
                if watermark is not None and (self.start_us is None or watermark > self.start_us):
                    yield from asm.drain(watermark)
                if self.end_us is not None and watermark is not None and watermark > self.end_us:
                    break
            else:
                yield from asm.drain(None)
                if self._tail:
                    raise self.error(
                        f"truncated record ({self._tail} of 8 bytes)", self._data_start + 8 * self.n_records
                    )
            yield from asm.drain(None)
        finally:
            fh.close()
            if state[0] or state[1]:
                counts["incomplete"] += 1
            incomplete = int(state[5]) + counts["incomplete"]
            if incomplete:
                self.warn(f"{incomplete} incomplete APS frames dropped (not every pixel read)")
            if counts["odd_exposure"]:
                self.warn(f"{counts['odd_exposure']} frames dropped: no time between first reset and signal read")
            if counts["imu_bad"]:
                self.warn(f"{counts['imu_bad']} IMU words dropped (not in complete groups of 7)")
            if counts["frames"] == 0 and self.start_us is None and self.end_us is None:
                self.exposure_source = "none (no frames)"

    def _decode(self, addr, t, asm, W, H, reset, signal, rseen, sseen, state, counts, lag, seq) -> int:
        aps_bit = (addr >> 31).astype(bool)
        sub = (addr >> 10) & 3
        # DVS events
        dvs = ~aps_bit & (sub & 1 == 0)
        a = addr[dvs]
        x = W - 1 - ((a >> 12) & 0x3FF).astype(np.int32)
        y = H - 1 - ((a >> 22) & 0x1FF).astype(np.int32)
        ok = (x >= 0) & (y >= 0)
        if not ok.all():
            asm.counts["events_off_sensor"] += int((~ok).sum())
        ev = np.empty(int(ok.sum()), EVENT_DTYPE)
        ev["t"] = t[dvs][ok]
        ev["x"] = x[ok]
        ev["y"] = y[ok]
        ev["p"] = ((a[ok] >> 11) & 1).astype(np.int8) * 2 - 1
        # external inputs
        ext = ~aps_bit & (sub & 1 == 1)
        if ext.any():
            code = (addr[ext] & 0x3FF).astype(np.int64)
            kind = np.full(code.size, -1, np.int8)
            for c, k in EXT_TO_TRIGGER.items():
                kind[code == c] = k
            good = kind >= 0
            trg = np.empty(int(good.sum()), TRIGGER_DTYPE)
            trg["t"] = t[ext][good]
            trg["kind"] = kind[good]
            asm.push_triggers(trg)
        # APS samples -> frames
        aps = aps_bit & (sub < 2)
        nf = 0
        if aps.any():
            a = addr[aps]
            nsig = int(np.count_nonzero((a >> 10) & 3 == 1))
            cap = nsig // (W * H) + 1
            out_img = np.empty((cap, W * H), np.uint8)
            out_t = np.empty((cap, 3), np.int64)
            nf = assemble_aps(
                ((a >> 10) & 3).astype(np.int8),
                (W - 1 - ((a >> 12) & 0x3FF).astype(np.int32)),
                (H - 1 - ((a >> 22) & 0x1FF).astype(np.int32)),
                (a & 0x3FF).astype(np.int32),
                t[aps],
                W,
                H,
                reset,
                signal,
                rseen,
                sseen,
                state,
                out_img,
                out_t,
            )
        asm.push_events(ev)
        for k in range(nf):
            first_reset, first_signal, _ = (int(v) for v in out_t[k])
            if self.exposure_us is not None:
                s, e = first_signal - int(round(self.exposure_us)), first_signal
            else:
                s, e = first_reset, first_signal
            lag = max(lag, asm.lag_of(s))
            if e > s:
                asm.push_frame(Frame(out_img[k].reshape(H, W).copy(), s, e, 1.0, seq + k))
            else:
                counts["odd_exposure"] += 1
        counts["frames"] += nf
        return lag

    def _imu(self, addr, t, asm, carry, counts) -> np.ndarray:
        m = (addr & 0x80000C00) == 0x80000C00
        words = np.empty(int(m.sum()), RECORD)
        words["addr"] = addr[m]
        words["ts"] = 0
        tt = t[m]
        if carry.size:
            words = np.concatenate([carry, words])
            tt = np.concatenate([self._carry_t, tt])
        if words.size == 0:
            self._carry_t = np.zeros(0, np.int64)
            return words
        code = ((words["addr"] >> 28) & 7).astype(np.int64)
        n = code.size
        starts = np.flatnonzero(code == 0)
        full = starts[starts + 7 <= n]
        good = np.ones(full.size, bool)
        for k in range(1, 7):
            good &= code[full + k] == k
        full = full[good]
        used = full.size * 7
        pending = starts[starts + 7 > n]
        keep_from = int(pending[0]) if pending.size else n
        counts["imu_bad"] += keep_from - used
        raw = ((words["addr"] >> 12) & 0xFFFF).astype(np.uint16).view(np.int16).astype(np.float32)
        imu = np.empty(full.size, IMU_DTYPE)
        imu["t"] = tt[full]
        for k, name in enumerate(("ax", "ay", "az")):
            imu[name] = raw[full + k] / ACCEL_LSB_PER_G
        imu["temp"] = raw[full + 3] / 340.0 + 35.0
        for k, name in enumerate(("gx", "gy", "gz")):
            imu[name] = raw[full + 4 + k] / GYRO_LSB_PER_DPS
        asm.push_imu(imu)
        self._carry_t = tt[keep_from:]
        return words[keep_from:]
