"""``necviz bench decode``: DAVIS word-stream decoder throughput on a 12 Mev/s-style stream.

The stream is what a DAVIS346 sends at its peak rate: ``rate`` events per second of sensor time,
uniformly random pixels and polarities (so nearly every event needs its own row word), one timestamp
word per microsecond that has events, wrap words, 50 fps 346x260 frames (reset and signal readout,
exposure words) and 1 kHz IMU samples — encoded once by :class:`~necviz.drivers.davis.StreamEncoder`.

Two timings (after a warm-up that compiles every kernel):

* ``transfers``: the driver's path — :meth:`DavisDecoder.decode` on 128 KiB transfers, producing
  event batches, markers, frames and IMU packets;
* ``kernel``: the Numba state machine alone on the same transfers (no packet building);
* ``floor``: a read-only Numba pass over the same transfers (it reads every word and counts the
  event-address words, so it cannot be optimised away): what any decoder costs at least on this
  word stream. The ratios ``transfers / floor`` and ``kernel / floor`` are measured in the same run
  and say how close decoding runs to reading; the absolute rates move with the machine's load.

Mev/s = events decoded / wall time, mean ± std and best of ``repeats`` runs; ``x_sensor_max`` =
best Mev/s / 12. The target (>= 100 Mev/s, more than 8x the sensor's peak) is judged on the best run
of the driver path: on a shared machine other processes only ever slow a run down.
"""

from __future__ import annotations

import time

import numba as nb
import numpy as np

from necviz.bench.timing import machine, write_result
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE
from necviz.core.sensor import DAVIS346
from necviz.drivers.davis.decoder import DavisDecoder
from necviz.drivers.davis.decoder_kernels import C_IMU_MODEL, C_SIZE, S_LAST_Y, S_NEV, S_RTYPE, S_SIZE, decode_words
from necviz.drivers.davis.encoder import StreamEncoder, cds_pair
from necviz.progress import output

SENSOR_MAX_MEVS = 12.0
TARGET_MEVS = 100.0
TRANSFER_BYTES = 128 * 1024


def synthetic_words(
    seconds: float = 1.0,
    rate_mevs: float = 12.0,
    fps: float = 50.0,
    exposure_us: int = 5000,
    imu_hz: float = 1000.0,
    seed: int = 0,
) -> tuple[np.ndarray, int, int]:
    """Encode ``seconds`` of a DAVIS346 stream; returns (words, events, frames)."""
    rng = np.random.default_rng(seed)
    dur = int(seconds * 1e6)
    n = int(rate_mevs * 1e6 * seconds)
    ev = np.empty(n, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(0, dur, n))
    ev["x"] = rng.integers(0, DAVIS346.width, n)
    ev["y"] = rng.integers(0, DAVIS346.height, n)
    ev["p"] = rng.choice(np.array([-1, 1], np.int8), n)
    enc = StreamEncoder()
    img = rng.integers(0, 256, DAVIS346.shape)
    reset, signal = cds_pair(img)
    reset_flat = np.full(DAVIS346.shape, 1023)
    period = int(1e6 / fps)
    imu_period = int(1e6 / imu_hz)
    # cut points: frame start/exposure end/frame end and IMU times, in time order
    cuts = []
    for s in range(1000, dur - exposure_us - 2000, period):
        cuts += [(s, 0), (s + exposure_us, 1), (s + exposure_us + 1000, 2)]
    cuts += [(t, 3) for t in range(500, dur, imu_period)]
    cuts.sort()
    t = np.ascontiguousarray(ev["t"])  # searching a strided field view would copy it per call
    pos = 0
    parts = [enc.timestamp_reset()]
    frames = 0
    for tc, kind in cuts:
        end = int(np.searchsorted(t, tc, side="left"))
        parts.append(enc.events(ev[pos:end]))
        pos = end
        if kind == 0:
            parts += [
                enc.frame_start(tc, (0, 0, DAVIS346.width - 1, DAVIS346.height - 1), round(exposure_us * 30)),
                enc.readout(reset_flat, False),
                enc.special(tc, 14),
            ]
        elif kind == 1:
            parts.append(enc.special(tc, 15))
        elif kind == 2:
            parts += [enc.readout(signal, True), enc.special(tc, 10)]
            frames += 1
        else:
            parts.append(enc.imu(tc, (0, -8192, 0, -1700, 3, 4, 5)))
    parts.append(enc.events(ev[pos:]))
    return np.concatenate(parts), n, frames


def _kernel_only(chunks, width, height):
    st = np.zeros(S_SIZE, np.int64)
    st[S_LAST_Y] = -1
    st[S_RTYPE] = -1
    cfg = np.zeros(C_SIZE, np.int64)
    cfg[:5] = (width, height, 0, width, height)
    cfg[C_IMU_MODEL] = 1
    ev = np.empty(1 << 16, EVENT_DTYPE)
    mk = np.empty((4096, 4), np.int64)
    imu_t = np.empty(1024, np.int64)
    imu_v = np.empty((1024, 7), np.float32)
    reset_buf = np.zeros(width * height, np.int64)
    frame = np.zeros(height * width, np.uint16)
    events = 0
    for words in chunks:
        pos = 0
        while pos < words.shape[0]:
            pos = decode_words(words, pos, st, cfg, ev, mk, imu_t, imu_v, reset_buf, frame)
            events += int(st[S_NEV])
    return events


@nb.njit(cache=True)
def read_floor(words):
    """Read every 16-bit word once: the number whose top nibble marks a DVS address (codes 1..3).
    The least any decoder of this stream must do. O(words)."""
    n = 0
    for i in range(words.shape[0]):
        code = words[i] >> 12
        n += (code >= 1) & (code <= 3)
    return n


def _floor(chunks):
    return sum(int(read_floor(c)) for c in chunks)


def run(seconds: float = 1.0, repeats: int = 5, seed: int = 0, json_path=None, out=...) -> dict:
    """Run the benchmark, print a table, optionally write JSON; returns the result dict."""
    out = output(out)
    if not (0.05 <= seconds <= 10) or repeats < 1:
        raise ParameterError("decode benchmark needs 0.05 <= seconds <= 10 and repeats >= 1")
    print(f"encoding {seconds:g} s of a {SENSOR_MAX_MEVS:g} Mev/s DAVIS346 stream ...", file=out, flush=True)
    words, n_events, n_frames = synthetic_words(seconds, seed=seed)
    per = TRANSFER_BYTES // 2
    chunks = [words[i : i + per] for i in range(0, words.size, per)]
    # warm-up: compile (or load from cache) on a small slice
    warm = DavisDecoder()
    warm.decode(words[: min(words.size, 400_000)])
    _kernel_only([words[:1000]], DAVIS346.width, DAVIS346.height)
    _floor([words[:1000]])

    def via_decoder():
        dec = DavisDecoder()
        for c in chunks:
            dec.decode(c)
        st = dec.stats
        if st["events"] != n_events or st["frames"] != n_frames or st["skipped_words"]:
            raise RuntimeError(f"decoder output mismatch: {st}")
        return st["events"]

    def kernel():
        return _kernel_only(chunks, DAVIS346.width, DAVIS346.height)

    rows = []
    print(
        f"{'path':10s} {'Mev/s':>9s} {'± std':>7s} {'best':>7s} {'Mwords/s':>9s} {'x 12 Mev/s':>11s} {'s/run':>7s}",
        file=out,
        flush=True,
    )
    paths = (("transfers", via_decoder), ("kernel", kernel), ("floor", lambda: _floor(chunks)))
    all_times = {name: [] for name, _ in paths}
    for _ in range(repeats):  # interleaved: each repeat times every path, so load hits them alike
        for name, fn in paths:
            a = time.perf_counter()
            fn()
            all_times[name].append(time.perf_counter() - a)
    for name, _ in paths:
        times = np.array(all_times[name])
        rate = n_events / times / 1e6
        row = {
            "path": name,
            "mev_per_s": float(rate.mean()),
            "mev_per_s_std": float(rate.std(ddof=1)) if repeats > 1 else 0.0,
            "mev_per_s_best": float(rate.max()),
            "mwords_per_s": float((words.size / times / 1e6).mean()),
            "x_sensor_max": float(rate.max() / SENSOR_MAX_MEVS),
            "seconds_per_run": float(times.mean()),
        }
        rows.append(row)
        print(
            f"{name:10s} {row['mev_per_s']:9.1f} {row['mev_per_s_std']:7.1f} {row['mev_per_s_best']:7.1f} "
            f"{row['mwords_per_s']:9.1f} {row['x_sensor_max']:11.1f} {row['seconds_per_run']:7.3f}",
            file=out,
            flush=True,
        )
    floor = rows[2]["mev_per_s_best"]
    for row in rows:
        row["fraction_of_floor"] = row["mev_per_s_best"] / floor
    print(
        f"same run: driver path {rows[0]['fraction_of_floor']:.2f} and kernel {rows[1]['fraction_of_floor']:.2f} of the "
        f"read-only floor ({floor:.0f} Mev/s over the same words)",
        file=out,
    )
    ok = rows[0]["mev_per_s_best"] >= TARGET_MEVS
    print(f"target >= {TARGET_MEVS:g} Mev/s (best run, driver path): {'met' if ok else 'NOT met'}", file=out)
    result = {
        "rows": rows,
        "target_mev_per_s": TARGET_MEVS,
        "target_met": ok,
        "stream": {
            "seconds": seconds,
            "events": n_events,
            "words": int(words.size),
            "words_per_event": float(words.size / n_events),
            "frames": n_frames,
            "transfer_bytes": TRANSFER_BYTES,
            "rate_mevs": SENSOR_MAX_MEVS,
            "repeats": repeats,
            "seed": seed,
        },
        "machine": machine(),
    }
    write_result(result, json_path, out)
    return result
