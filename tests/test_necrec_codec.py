"""The native format's compressed chunks (version 2): exact round trips, and the size it saves on a live stream."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from necviz.commands.cli import main
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings import open_recording
from necviz.drivers.recordings.native import (
    CODECS,
    Recorder,
    decode_events,
    decode_pixels,
    encode_events,
    encode_pixels,
)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 400),
    seed=st.integers(0, 2**31),
    step=st.sampled_from([0, 3, 300, 70_000, 5_000_000_000]),
    codec=st.sampled_from(sorted(CODECS.values())),
    shuffled=st.booleans(),
)
def test_event_chunks_decode_to_exactly_what_was_written(n, seed, step, codec, shuffled):
    rng = np.random.default_rng(seed)
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = 10**12 + np.cumsum(rng.integers(0, step + 1, n))
    if shuffled:  # a chunk that is not time-sorted still round-trips
        ev["t"] = rng.permutation(ev["t"])
    ev["x"], ev["y"] = rng.integers(0, 2**16, n), rng.integers(0, 2**16, n)
    ev["p"] = rng.integers(-128, 128, n)
    np.testing.assert_array_equal(decode_events(encode_events(ev, codec)), ev)


@settings(max_examples=30, deadline=None)
@given(h=st.integers(1, 40), w=st.integers(1, 40), seed=st.integers(0, 2**31), codec=st.sampled_from([0, 1, 2]))
def test_frame_pixels_decode_to_exactly_what_was_written(h, w, seed, codec):
    img = np.random.default_rng(seed).integers(0, 256, (h, w), dtype=np.uint8)
    np.testing.assert_array_equal(decode_pixels(encode_pixels(img, codec), h, w), img)


@pytest.mark.parametrize("compression", sorted(CODECS))
def test_a_recording_reads_back_equal_with_every_compression(tmp_path, compression):
    rng = np.random.default_rng(1)
    ev = np.zeros(5000, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(0, 100_000, 5000))
    ev["x"], ev["y"], ev["p"] = rng.integers(0, 346, 5000), rng.integers(0, 260, 5000), rng.choice([-1, 1], 5000)
    img = rng.integers(0, 256, (260, 346), dtype=np.uint8)
    path = tmp_path / f"{compression}.necrec"
    with Recorder(path, sensor=SensorGeometry(346, 260, "DAVIS346"), compression=compression) as rec:
        rec.write(EventBatch(ev[:2500]))
        rec.write(Frame(img, 50_000, 52_000, 1.5, 7))
        rec.write(EventBatch(ev[2500:]))
    out = list(open_recording(path))
    got = np.concatenate([p.events for p in out if isinstance(p, EventBatch)])
    np.testing.assert_array_equal(got, ev)
    (frame,) = [p for p in out if isinstance(p, Frame)]
    np.testing.assert_array_equal(frame.image, img)
    assert (frame.exposure_start_us, frame.exposure_end_us, frame.gain, frame.sequence) == (50_000, 52_000, 1.5, 7)


@pytest.mark.slow
def test_two_seconds_of_emulated_live_record_in_at_most_25_mb(tmp_path):
    """The emulated DAVIS346 streams ~2.7 Mev/s and 50 frames a second: 13 bytes an event and a frame's
    pixels as they are would be ~80 MB for 2 s; compressed, at most a third of that and under 25 MB."""
    rec, rrd = tmp_path / "live.necrec", tmp_path / "live.rrd"
    argv = ["live", "--device", "emulated", "--duration", "2", "--record", str(rec), "--save", str(rrd), "--no-prompt"]
    assert main(argv) == 0
    n_events = n_pixels = 0
    for p in open_recording(rec):
        if isinstance(p, EventBatch):
            n_events += len(p)
        elif isinstance(p, Frame):
            n_pixels += p.image.size
    uncompressed = 13 * n_events + n_pixels  # what version 1 stored for them (headers left out)
    size = rec.stat().st_size
    assert n_events > 2_000_000 and n_pixels >= 90 * 346 * 260  # the whole live stream was recorded
    assert size <= 25e6
    assert size <= uncompressed / 3
