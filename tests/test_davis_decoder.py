"""DAVIS word-stream decoder: encoder→decoder round trips, split transfers, garbage, wraps and resets.

The expected values come from the generator of each test (what it asked the encoder to write) and
from the formulas in docs/davis-protocol.md (CDS rule, IMU scales), not from the decoder.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from necviz.core.events import EVENT_DTYPE, validate_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, TRIGGER_KINDS, ImuBatch, TriggerBatch
from necviz.drivers.davis import DavisDecoder, DecoderOptions, FrameTiming, StreamEncoder
from necviz.drivers.davis.encoder import cds_pair

HYP = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ---------------------------------------------------------------------------------------------
# a stream generator that records what it encoded
# ---------------------------------------------------------------------------------------------
class Expect:
    """What a decoder must output for the words the generator wrote."""

    def __init__(self, w, h):
        self.w, self.h = w, h
        self.events = []
        self.markers = []  # ("start"|"end", t)
        self.frames = []  # (image, es, ee)
        self.imu = []  # (t, 7 values)
        self.triggers = []  # (t, kind)
        self.offset = 0  # output time = offset + device time


def random_events(rng, n, t0, t1, w, h):
    ev = np.empty(n, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(t0, t1 + 1, n))
    ev["x"] = rng.integers(0, w, n)
    ev["y"] = rng.integers(0, h, n)
    ev["p"] = rng.choice(np.array([-1, 1], np.int8), n)
    return ev


def expected_z8(reset, signal):
    """Doc §2.1: saturated if reset < 384 or signal == 0, else clip(reset - signal, 0, 1023); then >> 2."""
    z10 = np.where((reset < 384) | (signal == 0), 1023, np.clip(reset - signal, 0, 1023))
    return (z10 >> 2).astype(np.uint8)


def expected_imu(raw, ascale, gscale, sensors, model=1):
    """Doc §2.2: accel LSB/g = 65536/(4<<s), gyro LSB/(°/s) = 65536/(500<<s), T = raw/340 + 35."""
    a = [r / (65536 / (4 << ascale)) for r in raw[:3]]
    g = [r / (65536 / (500 << gscale)) for r in raw[4:]]
    temp = raw[3] / 340 + 35 if model == 1 else raw[3] / 333.87 + 21
    nan = float("nan")
    return (a if sensors & 4 else [nan] * 3) + (g if sensors & 2 else [nan] * 3) + [temp if sensors & 1 else nan]


def gen_stream(seed, w, h, orientation=0, segments=8, garbage_at=None):
    """Random valid stream: event runs, frames (events inside their exposure), IMU samples, triggers,
    timestamp resets and long gaps (many wraps). Returns (words, Expect)."""
    rng = np.random.default_rng(seed)
    enc = StreamEncoder(aps_orientation=orientation, always_y=bool(rng.integers(0, 2)))
    ex = Expect(w, h)
    parts = [enc.timestamp_reset()]
    ex.triggers.append((0, TRIGGER_KINDS.index("timestamp_reset")))
    t = int(rng.integers(0, 5000))

    def add_events(t0, t1, n):
        ev = random_events(rng, n, t0, t1, w, h)
        parts.append(enc.events(ev))
        out = ev.copy()
        out["t"] += ex.offset
        ex.events.append(out)

    for seg in range(segments):
        if garbage_at is not None and seg == garbage_at[0]:
            parts.append(np.asarray(garbage_at[1], np.uint16))
            enc.state[2] = -1  # the device's next event repeats its row word
        kind = rng.choice(["events", "frame", "imu", "trigger", "gap", "reset"], p=[0.3, 0.3, 0.15, 0.1, 0.1, 0.05])
        if kind == "events":
            t1 = t + int(rng.integers(0, 70_000))
            add_events(t, t1, int(rng.integers(0, 300)))
            t = t1
        elif kind == "gap":
            t += int(rng.choice([32768, 65536 * 3, 4095 * 32768 + 5, 5000 * 32768 + 17]))
        elif kind == "frame":
            c0, c1 = sorted(rng.integers(0, w, 2))
            r0, r1 = sorted(rng.integers(0, h, 2))
            fh, fw = r1 - r0 + 1, c1 - c0 + 1
            reset = rng.integers(300, 1024, (fh, fw))
            signal = rng.integers(0, 1024, (fh, fw))
            cycles = int(rng.integers(0, 1 << 30))
            ts, es = t, t + int(rng.integers(0, 50))
            ee = es + int(rng.integers(1, 20_000))
            fe = ee + int(rng.integers(0, 2000))
            parts += [
                enc.frame_start(ts, (c0, r0, c1, r1), cycles, bool(rng.integers(0, 2))),
                enc.readout(reset, False),
                enc.special(es, 14),
            ]
            ex.markers.append(("start", es + ex.offset))
            add_events(es, ee, int(rng.integers(0, 100)))
            parts.append(enc.special(ee, 15))
            ex.markers.append(("end", ee + ex.offset))
            add_events(ee, fe, int(rng.integers(0, 30)))
            parts += [enc.readout(signal, True), enc.special(fe, 10)]
            img = np.zeros((h, w), np.uint8)
            img[r0 : r1 + 1, c0 : c1 + 1] = expected_z8(reset, signal)
            ex.frames.append((img, es + ex.offset, ee + ex.offset, cycles))
            t = fe
        elif kind == "imu":
            raw = [int(v) for v in rng.integers(-32768, 32768, 7)]
            a, g, sensors = int(rng.integers(0, 4)), int(rng.integers(0, 4)), int(rng.integers(1, 8))
            parts.append(enc.imu(t, raw, a, g, sensors))
            ex.imu.append((t + ex.offset, expected_imu(raw, a, g, sensors)))
        elif kind == "trigger":
            name = str(
                rng.choice(
                    ["external_rising", "external_falling", "external_pulse", "generator_rising", "generator_falling"]
                )
            )
            parts.append(enc.trigger(t, name))
            ex.triggers.append((t + ex.offset, TRIGGER_KINDS.index(name)))
        else:  # timestamp reset: device time restarts at 0, output continues from here
            ex.offset += enc.now_us
            parts.append(enc.timestamp_reset())
            ex.triggers.append((ex.offset, TRIGGER_KINDS.index("timestamp_reset")))
            t = int(rng.integers(0, 100))
        t += int(rng.integers(0, 3))
    return np.concatenate(parts), ex


def summarise(packets):
    """Split a packet list into comparable parts, checking the stream-order contract on the way."""
    evs, markers, frames, imu, trig = [], [], [], [], []
    open_start = None
    last_end = None
    last_t = -1
    for p in packets:
        if isinstance(p, np.ndarray):
            validate_events(p)
            if p.size:
                assert int(p["t"][0]) >= last_t, "event batches must not go back in time"
                last_t = int(p["t"][-1])
            evs.append(p)
        elif isinstance(p, ExposureMarker):
            assert p.t_us >= last_t, "a marker must not precede events already delivered"
            last_t = p.t_us
            markers.append((p.kind, p.t_us))
            if p.kind == "start":
                assert open_start is None
                open_start = p.t_us
            else:
                assert open_start is not None and p.t_us > open_start
                last_end = (open_start, p.t_us)
                open_start = None
        elif isinstance(p, Frame):
            assert last_end == (p.exposure_start_us, p.exposure_end_us), "a frame follows its end marker"
            frames.append(p)
        elif isinstance(p, ImuBatch):
            imu.append(p.samples)
        elif isinstance(p, TriggerBatch):
            trig.append(p.triggers)
        else:
            raise AssertionError(f"unexpected packet {p!r}")
    cat = lambda xs, dt: np.concatenate(xs) if xs else np.zeros(0, dt)  # noqa: E731
    return cat(evs, EVENT_DTYPE), markers, frames, cat(imu, IMU_DTYPE), cat(trig, TRIGGER_DTYPE)


def decode_split(words, cuts, w, h, orientation=0):
    """Decode the byte stream cut at the given byte offsets (odd offsets split words)."""
    raw = words.tobytes()
    dec = DavisDecoder(DecoderOptions(w, h, aps_orientation=orientation))
    packets = []
    prev = 0
    for c in sorted(set(cuts)) + [len(raw)]:
        packets += dec.decode(raw[prev:c])
        prev = c
    return packets, dec


def check_against(ex: Expect, summary, dec):
    ev, markers, frames, imu, trig = summary
    want = np.concatenate(ex.events) if ex.events else np.zeros(0, EVENT_DTYPE)
    assert ev.size == want.size
    assert np.array_equal(ev, want)
    assert markers == ex.markers
    assert len(frames) == len(ex.frames)
    for f, (img, es, ee, cycles) in zip(frames, ex.frames, strict=True):
        assert (f.exposure_start_us, f.exposure_end_us) == (es, ee)
        assert np.array_equal(f.image, img)
        assert dec.frame_cycles.get(f.sequence, cycles) == cycles
    assert [int(t) for t in imu["t"]] == [t for t, _ in ex.imu]
    for row, (_, vals) in zip(imu, ex.imu, strict=True):
        got = [float(row[k]) for k in ("ax", "ay", "az", "gx", "gy", "gz", "temp")]
        np.testing.assert_allclose(got, vals, rtol=1e-6, atol=1e-6)
    assert [(int(a), int(b)) for a, b in trig] == ex.triggers


# ---------------------------------------------------------------------------------------------
# round trips
# ---------------------------------------------------------------------------------------------
@HYP
@given(
    seed=st.integers(0, 2**32 - 1),
    size=st.sampled_from([(8, 6), (17, 11), (40, 30)]),
    orientation=st.integers(0, 7),
    data=st.data(),
)
def test_round_trip_split_at_random_transfer_boundaries(seed, size, orientation, data):
    w, h = size
    words, ex = gen_stream(seed, w, h, orientation)
    nbytes = 2 * words.size
    cuts = data.draw(st.lists(st.integers(0, nbytes), max_size=12))
    whole, dec_whole = decode_split(words, [], w, h, orientation)
    split, dec_split = decode_split(words, cuts, w, h, orientation)
    s_whole, s_split = summarise(whole), summarise(split)
    check_against(ex, s_whole, dec_whole)
    check_against(ex, s_split, dec_split)
    assert dec_whole.stats == dec_split.stats
    assert dec_whole.stats["skipped_words"] == 0
    assert dec_whole.stats["frames_dropped"] == 0


def test_full_size_frame_round_trip_on_davis346():
    rng = np.random.default_rng(3)
    z = rng.integers(0, 256, (260, 346))
    reset, signal = cds_pair(z)
    enc = StreamEncoder()
    words = np.concatenate(
        [enc.timestamp_reset(), enc.frame(FrameTiming(10, 20, 4020, 5000), reset, signal, exposure_cycles=120960)]
    )
    dec = DavisDecoder()
    packets = dec.decode(words.tobytes())
    frame = [p for p in packets if isinstance(p, Frame)][0]
    assert np.array_equal(frame.image, z)
    assert (frame.exposure_start_us, frame.exposure_end_us) == (20, 4020)
    assert dec.last_frame_exposure_cycles == 120960


def test_cds_rule_saturation_and_clipping():
    enc = StreamEncoder()
    reset = np.array([[383, 1023, 500, 1023]])
    signal = np.array([[10, 0, 600, 3]])  # dark reset, zero signal, signal > reset, normal
    words = np.concatenate([enc.timestamp_reset(), enc.frame(FrameTiming(0, 1, 2, 3), reset, signal)])
    frame = [p for p in DavisDecoder(DecoderOptions(4, 1)).decode(words) if isinstance(p, Frame)][0]
    assert frame.image.tolist() == [[255, 255, 0, (1020 >> 2)]]


@pytest.mark.parametrize("orientation", range(8))
def test_flips_put_pixels_in_image_coordinates(orientation):
    """A gradient image survives every orientation; the sensor's readout order differs each time."""
    h, w = 5, 7
    z = (np.arange(h * w).reshape(h, w) * 7) % 256
    reset, signal = cds_pair(z)
    enc = StreamEncoder(aps_orientation=orientation)
    words = np.concatenate([enc.timestamp_reset(), enc.frame(FrameTiming(0, 1, 2, 3), reset, signal)])
    frame = [
        p for p in DavisDecoder(DecoderOptions(w, h, aps_orientation=orientation)).decode(words) if isinstance(p, Frame)
    ][0]
    assert np.array_equal(frame.image, z)
    # and the same words read with no orientation give a different (transposed/flipped) picture
    if orientation:
        other = [p for p in DavisDecoder(DecoderOptions(w, h)).decode(words) if isinstance(p, Frame)]
        assert not other or not np.array_equal(other[0].image, z)


def test_dvs_invert_xy_swaps_row_and_column_words():
    words = np.array([0x0001, 0x8005, 0x1000 | 9, 0x3000 | 2], np.uint16)  # row word 9, column word 2
    ev = [
        p for p in DavisDecoder(DecoderOptions(16, 12, dvs_invert_xy=True)).decode(words) if isinstance(p, np.ndarray)
    ][0]
    assert (int(ev["x"][0]), int(ev["y"][0]), int(ev["p"][0]), int(ev["t"][0])) == (9, 2, 1, 5)


# ---------------------------------------------------------------------------------------------
# time: wraps, resets, regressions
# ---------------------------------------------------------------------------------------------
def test_timestamps_wrap_reset_and_never_decrease():
    enc = StreamEncoder()
    ev1 = random_events(np.random.default_rng(1), 200, 0, 200_000, 16, 12)  # crosses 6 wraps
    ev2 = random_events(np.random.default_rng(2), 50, 0, 1000, 16, 12)
    words = np.concatenate(
        [enc.timestamp_reset(), enc.events(ev1), enc.time(250_000), enc.timestamp_reset(), enc.events(ev2)]
    )
    dec = DavisDecoder(DecoderOptions(16, 12))
    ev = np.concatenate([p for p in dec.decode(words) if isinstance(p, np.ndarray)])
    assert np.array_equal(ev["t"][:200], ev1["t"])
    # after the reset the device restarts at 0: output continues from the time reached (250 ms)
    assert np.array_equal(ev["t"][200:], ev2["t"] + 250_000)
    assert np.all(np.diff(ev["t"]) >= 0)


def test_many_wraps_in_one_gap_and_a_time_offset():
    enc = StreamEncoder()
    t_big = 6000 * 32768 + 123  # needs two wrap words (4095 + 1905)
    ev = random_events(np.random.default_rng(0), 3, t_big, t_big + 10, 4, 4)
    words = np.concatenate([enc.timestamp_reset(), enc.events(ev)])
    assert int(np.sum((words >> 12) == 7)) == 2
    out = DavisDecoder(DecoderOptions(4, 4), time_offset_us=1000).decode(words)
    got = np.concatenate([p for p in out if isinstance(p, np.ndarray)])
    assert np.array_equal(got["t"], ev["t"] + 1000)


def test_backwards_timestamp_is_skipped_and_counted():
    words = np.array([0x0001, 0x8000 | 500, 0x1003, 0x3002, 0x8000 | 200, 0x3001, 0x8000 | 600, 0x2000], np.uint16)
    dec = DavisDecoder(DecoderOptions(8, 8))
    ev = np.concatenate([p for p in dec.decode(words) if isinstance(p, np.ndarray)])
    assert ev["t"].tolist() == [500, 500, 600]
    assert dec.stats["time_regressions"] == 1 and dec.stats["skipped_words"] == 1


# ---------------------------------------------------------------------------------------------
# garbage
# ---------------------------------------------------------------------------------------------
#: words that encode nothing usable between frames/IMU blocks (each must be skipped and counted once). ROI
#: words (0x51xx, 0x52xx) are not among them: libcaer takes them anywhere, and a frame's own ROI words replace
#: stray ones.
GARBAGE = [
    0x0000,
    0x0006,
    0x0012,
    0x0FFF,
    0x1FFF,
    0x2FFF,
    0x3FFF,
    0x4123,
    0x5042,
    0x5311,
    0x5A00,
    0x6400,
    0x6C00,
    0x7000,
    0x0007,
    0x000B,
    0x000C,
    0x000D,
    0x000E,
    0x000F,
    0x000A,
]


@HYP
@given(
    seed=st.integers(0, 2**32 - 1),
    garbage=st.lists(st.sampled_from(GARBAGE), min_size=1, max_size=40),
    where=st.integers(0, 7),
    cuts=st.lists(st.integers(0, 20_000), max_size=6),
)
def test_garbage_is_skipped_counted_and_the_stream_resynchronises(seed, garbage, where, cuts):
    """Invalid words between packets: everything else decodes exactly as if they were absent."""
    words, ex = gen_stream(seed, 17, 11, 0, garbage_at=(where, garbage))
    packets, dec = decode_split(words, cuts, 17, 11)
    check_against(ex, summarise(packets), dec)
    assert dec.stats["skipped_words"] == len(garbage)


@settings(max_examples=60, deadline=None)
@given(raw=st.binary(min_size=0, max_size=6000), cuts=st.lists(st.integers(0, 6000), max_size=5))
def test_random_bytes_never_crash_and_never_invent_events(raw, cuts):
    dec = DavisDecoder(DecoderOptions(16, 12))
    packets = []
    prev = 0
    for c in sorted(set(min(c, len(raw)) for c in cuts)) + [len(raw)]:
        packets += dec.decode(raw[prev:c])
        prev = c
    words = np.frombuffer(raw[: len(raw) & ~1], "<u2")
    x_words = int(np.sum(((words >> 12) == 2) | ((words >> 12) == 3)))
    ev, markers, frames, imu, trig = summarise(packets)  # the stream-order contract holds even for garbage
    assert ev.size <= x_words
    assert np.all(np.diff(ev["t"]) >= 0)
    assert ev.size == 0 or (int(ev["x"].max()) < 16 and int(ev["y"].max()) < 12)
    used = dec.stats["words"] - dec.stats["skipped_words"]
    assert 0 <= used <= words.size and dec.stats["words"] == words.size


def test_incomplete_frame_is_dropped_and_markers_still_pair():
    enc = StreamEncoder()
    z = np.full((3, 4), 100)
    reset, signal = cds_pair(z)
    full = enc.frame(FrameTiming(0, 1, 10, 20), reset, signal)
    cut = np.flatnonzero(full == 0x000D)[-1]  # drop the last signal column's end word
    words = np.concatenate([StreamEncoder().timestamp_reset(), full[:cut], full[cut + 1 :]])
    dec = DavisDecoder(DecoderOptions(4, 3))
    packets = dec.decode(words)
    assert not [p for p in packets if isinstance(p, Frame)]
    assert [(p.kind, p.t_us) for p in packets if isinstance(p, ExposureMarker)] == [("start", 1), ("end", 10)]
    assert dec.stats["frames_dropped"] == 1


def test_exposure_left_open_is_closed_by_the_next_frame_start():
    words = np.array(
        [
            0x0001,
            0x0008,
            0x5100,
            0x5200,
            0x5100,
            0x5200,
            0x5100,
            0x5200,
            0x5100,
            0x5200,
            0x8000 | 7,
            0x000E,
            0x8000 | 9,
            0x0008,
        ],
        np.uint16,
    )
    dec = DavisDecoder(DecoderOptions(4, 4))
    markers = [(p.kind, p.t_us) for p in dec.decode(words) if isinstance(p, ExposureMarker)]
    assert markers == [("start", 7), ("end", 9)]
    assert dec.stats["exposures_aborted"] == 1 and dec.stats["frames_dropped"] == 1


def test_imu_sample_with_missing_bytes_is_dropped():
    enc = StreamEncoder()
    good = enc.imu(5, [1, 2, 3, 4, 5, 6, 7])
    words = np.concatenate([StreamEncoder().timestamp_reset(), good[:-3], good[-1:]])  # two data bytes lost
    dec = DavisDecoder(DecoderOptions(4, 4))
    assert not [p for p in dec.decode(words) if isinstance(p, ImuBatch)]
    assert dec.stats["imu_dropped"] == 1


def test_event_batches_are_bounded():
    ev = random_events(np.random.default_rng(5), 150_000, 0, 1000, 16, 12)
    words = np.concatenate([StreamEncoder().timestamp_reset(), StreamEncoder().events(ev)])
    batches = [p for p in DavisDecoder(DecoderOptions(16, 12)).decode(words) if isinstance(p, np.ndarray)]
    assert max(b.size for b in batches) <= 1 << 16
    assert sum(b.size for b in batches) == ev.size


# ---------------------------------------------------------------------------------------------
# markers and events in one time order (issue 14)
# ---------------------------------------------------------------------------------------------
def _skew_stream(w=4, h=3):
    """A frame whose exposure starts and ends in the same µs (100), with events at 100 after the end
    word and at 200: the end marker is due at 101 — after the events at 100, before those at 200."""
    enc = StreamEncoder()
    reset, signal = cds_pair(np.full((h, w), 100))
    at100 = np.array([(100, 1, 1, 1), (100, 2, 0, -1)], EVENT_DTYPE)
    at200 = np.array([(200, 3, 2, 1)], EVENT_DTYPE)
    return np.concatenate(
        [
            enc.timestamp_reset(),
            enc.frame_start(50, (0, 0, w - 1, h - 1), 3),
            enc.readout(reset, False),
            enc.special(100, 14),
            enc.special(100, 15),
            enc.events(at100),
            enc.events(at200),
            enc.readout(signal, True),
            enc.special(300, 10),
        ]
    )


def _timeline(packets):
    """(time, kind) of events and markers in delivery order; frames as ("frame", start, end)."""
    out = []
    for p in packets:
        if isinstance(p, np.ndarray):
            out += [(int(t), "event") for t in p["t"]]
        elif isinstance(p, ExposureMarker):
            out.append((p.t_us, p.kind))
        elif isinstance(p, Frame):
            out.append(("frame", p.exposure_start_us, p.exposure_end_us))
    return out


def test_an_exposure_ending_in_the_microsecond_it_started_keeps_markers_after_its_events():
    """Was: the end marker at 101 µs came right after the end word, ahead of the events at 100 µs."""
    words = _skew_stream()
    want = [(100, "start"), (100, "event"), (100, "event"), (101, "end"), (200, "event"), ("frame", 100, 101)]
    dec = DavisDecoder(DecoderOptions(4, 3))
    assert _timeline(dec.decode(words)) == want
    assert dec.stats["frames_dropped"] == 0 and dec.stats["skipped_words"] == 0
    # the same at every transfer boundary (the pending end survives between calls)
    raw = words.tobytes()
    for cut in range(0, len(raw) + 1):
        packets, _ = decode_split(words, [cut], 4, 3)
        assert _timeline(packets) == want, cut
        summarise(packets)


def test_a_pending_end_marker_is_delivered_by_finish_and_by_a_wrap():
    enc = StreamEncoder()
    words = np.concatenate(
        [enc.timestamp_reset(), enc.frame_start(5, (0, 0, 1, 1)), enc.special(7, 14), enc.special(7, 15)]
    )
    dec = DavisDecoder(DecoderOptions(2, 2))
    assert _timeline(dec.decode(words)) == [(7, "start")]
    assert _timeline(dec.finish()) == [(8, "end")]
    assert dec.stats["exposures_aborted"] == 0
    # a wrap word moves time on: the end comes before the events of the new time
    dec = DavisDecoder(DecoderOptions(2, 2))
    later = np.array([(32768 + 3, 1, 1, 1)], EVENT_DTYPE)
    got = _timeline(dec.decode(np.concatenate([words, enc.events(later)])))
    assert got == [(7, "start"), (8, "end"), (32771, "event")]


def test_a_frame_start_in_the_microsecond_an_exposure_started_closes_it_in_time_order():
    enc = StreamEncoder()
    ev = np.array([(7, 0, 0, 1)], EVENT_DTYPE)
    words = np.concatenate(
        [
            enc.timestamp_reset(),
            enc.frame_start(5, (0, 0, 1, 1)),
            enc.special(7, 14),
            enc.frame_start(7, (0, 0, 1, 1)),
            enc.events(ev),
            enc.time(9),
        ]
    )
    dec = DavisDecoder(DecoderOptions(2, 2))
    packets = dec.decode(words)
    assert _timeline(packets) == [(7, "start"), (7, "event"), (8, "end")]
    assert dec.stats["exposures_aborted"] == 1
    summarise(packets)


# ---------------------------------------------------------------------------------------------
# properties on hostile input (issue 14): random and mutated word streams
# ---------------------------------------------------------------------------------------------
def _word():
    """Words biased towards the ones that mean something: specials 0..17, small rows/columns, time words."""
    meaningful = st.builds(lambda c, d: (c << 12) | d, st.integers(0, 7), st.integers(0, 24))
    imu_roi = st.builds(lambda sub, v: 0x5000 | (sub << 8) | v, st.integers(0, 3), st.integers(0, 255))
    time = st.builds(lambda t: 0x8000 | t, st.integers(0, 0x7FFF))
    return st.one_of(st.integers(0, 0xFFFF), meaningful, meaningful, imu_roi, time)


def _decode_checked(words, w, h, cuts=()):
    packets, dec = decode_split(np.asarray(words, np.uint16), list(cuts), w, h)
    packets += dec.finish()
    ev, markers, frames, imu, trig = summarise(packets)  # time order of events+markers, pairing, frames
    assert ev.size == 0 or (int(ev["x"].max()) < w and int(ev["y"].max()) < h), "event off the sensor"
    starts = [t for k, t in markers if k == "start"]
    ends = [t for k, t in markers if k == "end"]
    assert len(starts) == len(ends), "every exposure start gets its end"
    return ev, dec


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    words=st.lists(_word(), max_size=1500),
    size=st.sampled_from([(4, 3), (17, 11), (346, 260)]),
    cuts=st.lists(st.integers(0, 3000), max_size=4),
)
def test_random_word_streams_keep_every_invariant(words, size, cuts):
    """No crash, no event off the sensor, events and markers in one time order, markers paired,
    frames after their end marker — whatever the words and wherever the transfers split them."""
    w, h = size
    ev, dec = _decode_checked(words, w, h, cuts)
    x_words = sum(1 for v in words if (v >> 12) in (2, 3) and not v & 0x8000)
    assert ev.size <= x_words
    assert dec.stats["words"] == len(words)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), flips=st.lists(st.integers(0, 2**40), min_size=1, max_size=8))
def test_one_flipped_bit_adds_at_most_one_event(seed, flips):
    """A valid stream with one bit flipped (at each of several positions, one at a time): at most one
    event more than the clean stream, and every invariant still holds."""
    words, _ = gen_stream(seed, 17, 11)
    clean, _ = _decode_checked(words, 17, 11)
    for f in flips:
        bad = words.copy()
        bad[f % words.size] ^= np.uint16(1 << (f // words.size % 16))
        ev, _ = _decode_checked(bad, 17, 11)
        assert ev.size <= clean.size + 1


# ---------------------------------------------------------------------------------------------
# libcaer's acceptance rules (src/davis_common.h: apsInitFrame, apsROIUpdateSizes, apsEndFrame, the event
# translator) on the layouts a real camera may send
# ---------------------------------------------------------------------------------------------
def frames_stream(layout=None, n=3, w=6, h=4, orientation=0, seed=0, gap_events=True):
    """A clock reset then ``n`` frames (random images, exposure value 1000 + k cycles) with events between
    them, laid out as ``layout`` says. Returns (words, [(image, es, ee, cycles)], events)."""
    from necviz.drivers.davis import StreamLayout

    rng = np.random.default_rng(seed)
    enc = StreamEncoder(aps_orientation=orientation, layout=layout or StreamLayout())
    parts, want, evs = [enc.timestamp_reset()], [], []
    t = 100
    for k in range(n):
        z = rng.integers(0, 256, (h, w))
        reset, signal = cds_pair(z)
        timing = FrameTiming(t, t + 900, t + 900 + 300 * (k + 1), t + 3000)
        parts.append(enc.frame(timing, reset, signal, exposure_cycles=1000 + k))
        want.append((z.astype(np.uint8), timing.exposure_start_us, timing.exposure_end_us, 1000 + k))
        t += 5000
        if gap_events:
            ev = random_events(rng, 20, t - 1500, t - 100, w, h)
            parts.append(enc.events(ev))
            evs.append(ev)
    return np.concatenate(parts), want, (np.concatenate(evs) if evs else np.zeros(0, EVENT_DTYPE))


def frames_of(packets):
    return [p for p in packets if isinstance(p, Frame)]


@pytest.mark.parametrize("orientation", [0, 5])
def test_roi_and_exposure_value_before_the_frame_start_give_the_same_frames(orientation):
    """libcaer keeps ROI values from wherever they arrive (misc8 words are not gated by the frame); the
    exposure value sent before the start is kept for that frame (libcaer would reset it at apsInitFrame; the
    driver needs it to match commands)."""
    from necviz.drivers.davis import StreamLayout

    words, want, ev = frames_stream(StreamLayout(header="before"), orientation=orientation)
    start = np.flatnonzero(words == 0x0008)[0]
    assert words[start - 1] >> 12 == 5 and words[start + 1] >> 12 != 5  # the ROI words precede the start
    dec = DavisDecoder(DecoderOptions(6, 4, aps_orientation=orientation))
    packets = dec.decode(words)
    got = frames_of(packets)
    assert len(got) == 3 and dec.stats["frames_dropped"] == 0 and dec.stats["skipped_words"] == 0
    for f, (img, es, ee, cyc) in zip(got, want, strict=True):
        assert np.array_equal(f.image, img) and (f.exposure_start_us, f.exposure_end_us) == (es, ee)
        assert dec.frame_cycles[f.sequence] == cyc
    summarise(packets)  # the stream-order contract


def test_roi_words_once_serve_every_later_frame():
    """The ROI stays until the next complete one (libcaer's roi state is reset only in its update counter)."""
    words, want, _ = frames_stream()
    roi = ((words >> 8) == 0x51) | ((words >> 8) == 0x52)
    first_end = np.flatnonzero(words == 0x000A)[0]
    keep = ~roi | (np.arange(words.size) < first_end)
    dec = DavisDecoder(DecoderOptions(6, 4))
    got = frames_of(dec.decode(words[keep]))
    assert [f.image.tolist() for f in got] == [w[0].tolist() for w in want]


def test_no_roi_words_at_all_gives_no_frame():
    """Before any ROI the expected counts are unknown: libcaer's apsEndFrame sees wrong column counts."""
    words, _, ev = frames_stream()
    roi = ((words >> 8) == 0x51) | ((words >> 8) == 0x52)
    dec = DavisDecoder(DecoderOptions(6, 4))
    packets = dec.decode(words[~roi])
    assert not frames_of(packets) and dec.stats["frames_dropped"] == 3
    got_ev = np.concatenate([p for p in packets if isinstance(p, np.ndarray)])
    assert np.array_equal(got_ev, ev)  # events are unaffected


def test_a_missing_column_drops_the_frame_a_short_column_does_not():
    """apsEndFrame checks the column counts only; a wrong row count is only logged by libcaer."""
    words, want, _ = frames_stream(n=1)
    ends = np.flatnonzero(words == 0x000D)
    no_col = np.delete(words, ends[-1])
    dec = DavisDecoder(DecoderOptions(6, 4))
    assert not frames_of(dec.decode(no_col)) and dec.stats["frames_dropped"] == 1
    short = np.delete(words, ends[-1] - 1)  # the last sample of the last signal column
    got = frames_of(DavisDecoder(DecoderOptions(6, 4)).decode(short))
    assert len(got) == 1
    img = want[0][0].copy()
    img[3, 5] = 0  # the pixel that was not read (necviz starts every frame from zeros)
    assert np.array_equal(got[0].image, img)


def test_no_exposure_specials_the_decoder_places_the_exposure_from_the_readout():
    """libcaer accepts frames without specials 14/15; necviz needs markers in stream order. The first complete
    frame without them cannot be announced any more (counted), then every frame is delivered with its exposure
    from the readout: start when the reset read is done, end when the signal read starts."""
    from necviz.drivers.davis import StreamLayout

    words, want, ev = frames_stream(StreamLayout(exposure_specials=False), n=4)
    assert not np.any((words == 0x000E) | (words == 0x000F))
    dec = DavisDecoder(DecoderOptions(6, 4))
    packets = dec.decode(words)
    got = frames_of(packets)
    assert dec.stats["frames_without_exposure"] == 1 and dec.stats["frames_dropped"] == 0
    assert len(got) == 3
    for f, (img, es, ee, cyc) in zip(got, want[1:], strict=True):
        assert np.array_equal(f.image, img) and (f.exposure_start_us, f.exposure_end_us) == (es, ee)
        assert dec.frame_cycles[f.sequence] == cyc
    summarise(packets)
    # the same frames with the specials give the same result from the first frame on
    with_specials, _, _ = frames_stream(n=4)
    ref = frames_of(DavisDecoder(DecoderOptions(6, 4)).decode(with_specials))
    assert [(f.exposure_start_us, f.exposure_end_us) for f in ref[1:]] == [
        (f.exposure_start_us, f.exposure_end_us) for f in got
    ]


def test_rolling_shutter_without_specials_starts_the_exposure_after_the_first_reset_column():
    from necviz.drivers.davis import StreamLayout

    enc = StreamEncoder(layout=StreamLayout(exposure_specials=False))
    z = np.full((2, 3), 50)
    reset, signal = cds_pair(z)
    block = enc.readout(reset, False)
    per_col = block.size // 3
    parts = [enc.timestamp_reset()]
    for k, t0 in enumerate((100, 5000)):
        parts += [
            enc.frame_start(t0, (0, 0, 2, 1), 7, global_shutter=False),
            enc.time(t0 + 10),
            block[:per_col],  # first reset column at t0 + 10
            enc.time(t0 + 20),
            block[per_col:],
            enc.signal_start(t0 + 400 + k),
            enc.readout(signal, True, first_started=True),
            enc.special(t0 + 900, 10),
        ]
    got = frames_of(DavisDecoder(DecoderOptions(3, 2)).decode(np.concatenate(parts)))
    assert [(f.exposure_start_us, f.exposure_end_us) for f in got] == [(5010, 5401)]


def test_exposure_echo_is_read_before_or_after_the_frame_start_and_absent_is_minus_one():
    from necviz.drivers.davis import StreamLayout

    for layout in (StreamLayout(), StreamLayout(header="before")):
        words, want, _ = frames_stream(layout, n=2)
        dec = DavisDecoder(DecoderOptions(6, 4))
        got = frames_of(dec.decode(words))
        assert [dec.frame_cycles[f.sequence] for f in got] == [1000, 1001]
    words, _, _ = frames_stream(n=1)
    chunks = (words >> 12) == 6
    dec = DavisDecoder(DecoderOptions(6, 4))
    assert len(frames_of(dec.decode(words[~chunks]))) == 1 and dec.last_frame_exposure_cycles == -1


def test_timestamp_reset_as_libcaer_drops_the_frame_in_progress_keeps_the_roi_and_comes_in_order():
    """libcaer: time restarts at 0, the APS frame and IMU sample in progress are discarded and APS/IMU words are
    ignored until their next start, the ROI is kept, and the reset is committed alone after everything before
    it. necviz keeps output time increasing (offset by the time reached) and delivers the reset trigger between
    the events before and after it."""
    enc = StreamEncoder()
    z = np.full((4, 6), 80)
    reset, signal = cds_pair(z)
    before = np.array([(50, 1, 1, 1), (60, 2, 2, -1)], EVENT_DTYPE)
    after = np.array([(5, 3, 3, 1), (7, 4, 0, 1)], EVENT_DTYPE)
    frame1 = enc.frame(FrameTiming(100, 200, 400, 600), reset, signal)
    enc2 = StreamEncoder()
    half = enc2.frame(FrameTiming(10, 12, 14, 16), reset, signal)
    no_roi = half[~(((half >> 8) == 0x51) | ((half >> 8) == 0x52))]
    words = np.concatenate(
        [
            enc.timestamp_reset(),
            enc.events(before),
            frame1,
            enc.time(700),
            np.array([0x0008], np.uint16),  # a frame starts ...
            enc.readout(reset, False)[:10],  # ... and is cut by the reset
            enc.imu(710, [1, 2, 3, 4, 5, 6, 7])[:5],  # so is an IMU sample
            enc.timestamp_reset(),
            enc.events(after),
            enc.readout(reset, False)[:10],  # APS words before a frame start: ignored
            no_roi,  # a whole frame without ROI words, device time 10..16
        ]
    )
    dec = DavisDecoder(DecoderOptions(6, 4))
    packets = dec.decode(words)
    kinds = []
    for p in packets:
        if isinstance(p, np.ndarray):
            kinds += [("event", int(t)) for t in p["t"]]
        elif isinstance(p, TriggerBatch):
            kinds += [("trigger", int(t)) for t in p.triggers["t"]]
    resets = [i for i, k in enumerate(kinds) if k[0] == "trigger"]
    assert [kinds[i][1] for i in resets] == [0, 710]
    assert kinds[resets[1] - 1] == ("event", 60) and kinds[resets[1] + 1] == ("event", 715)
    got = frames_of(packets)
    assert len(got) == 2 and dec.stats["frames_dropped"] == 1 and dec.stats["imu_dropped"] == 1
    assert dec.stats["skipped_words"] == 0  # the cut frame's remaining words are ignored, not garbage
    assert np.array_equal(got[1].image, z) and got[1].exposure_start_us == 710 + 12


# ---------------------------------------------------------------------------------------------
# colour sensors: the Bayer mosaic demosaiced to grey as libcaer does
# ---------------------------------------------------------------------------------------------
#: libcaer's colorKeys (src/frame_utils.c): the channel of pixel (x, y) per filter, indexed (x & 1) << 1 | (y & 1)
LIBCAER_COLOR_KEYS = {
    1: "RGGB",  # RGBG: (0,0) R, (0,1) G2, (1,0) G1, (1,1) B
    2: "GBRG",  # GRGB
    3: "GRBG",  # GBGR
    4: "BGGR",  # BGRG
}


@pytest.mark.parametrize("color_filter", [1, 2, 3, 4])
@pytest.mark.parametrize("roi", [(0, 0, 11, 7), (3, 1, 10, 6)])
def test_colour_mosaic_is_demosaiced_to_grey(color_filter, roi):
    """A uniformly coloured scene seen through each Bayer layout (and through a ROI starting on an odd pixel,
    which shifts the filter's phase as libcaer's caerFrameUtilsPixelColor does) decodes to the grey of that
    colour, 0.299 R + 0.587 G + 0.114 B (the conversion OpenCV's Bayer-to-grey applies), not to a checkerboard
    of the three channels."""
    w, h = 12, 8
    rgb = {"R": 800, "G": 400, "B": 120}  # 10-bit channel values of the scene
    c0, r0, c1, r1 = roi
    z10 = np.empty((r1 - r0 + 1, c1 - c0 + 1), np.int64)
    for y in range(r0, r1 + 1):
        for x in range(c0, c1 + 1):
            z10[y - r0, x - c0] = rgb[LIBCAER_COLOR_KEYS[color_filter][(x & 1) << 1 | (y & 1)]]
    reset = np.full(z10.shape, 1023)
    enc = StreamEncoder()
    words = np.concatenate([enc.timestamp_reset(), enc.frame(FrameTiming(0, 1, 2, 3), reset, reset - z10, roi)])
    (f,) = frames_of(DavisDecoder(DecoderOptions(w, h, color_filter=color_filter)).decode(words))
    grey8 = (0.299 * rgb["R"] + 0.587 * rgb["G"] + 0.114 * rgb["B"]) / 4
    inside = f.image[r0 : r1 + 1, c0 : c1 + 1].astype(float)
    assert np.all(np.abs(inside - grey8) <= 1.0), (inside.min(), inside.max(), grey8)
    mask = np.ones((h, w), bool)
    mask[r0 : r1 + 1, c0 : c1 + 1] = False
    assert not f.image[mask].any()
    # a grey sensor reading the same words keeps the mosaic
    (g,) = frames_of(DavisDecoder(DecoderOptions(w, h)).decode(words))
    assert np.array_equal(g.image[r0 : r1 + 1, c0 : c1 + 1], (z10 >> 2).astype(np.uint8))
