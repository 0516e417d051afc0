"""Damaged recordings of every format end in a one-line error or a complete read (issue 14).

Hundreds of corrupted copies (tests/fuzz_corpus.py: truncation, bit flips, random bytes, huge length
fields, wrong magic, another format's header spliced in, deleted/duplicated/zeroed spans, broken
text columns) of small files written by the project's own writers and of the real DAVIS346 sample.
For each: either a :class:`~necviz.core.errors.NecvizError` whose message is one line naming the
file, or a read that completes; never a traceback, within 5 s and 200 MB. Seeded and deterministic.
The long run (10,000+ files, subprocess-isolated) is ``benchmarks/fuzz.py``.
"""

import signal
from collections import Counter
from contextlib import contextmanager

import numpy as np
import pytest
from format_writers import write_dsec
from fuzz_corpus import MUTATIONS, SAMPLE_AEDAT4, build_seeds, read_variant, remove, variants

from necviz.core.events import EventBatch
from necviz.drivers.recordings import RecordingError, describe, open_recording

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

TIME_LIMIT_S = 5.0
MEMORY_LIMIT = 200 * 1024 * 1024


@contextmanager
def _alarm(seconds):
    """Interrupt a read that hangs in Python code (the per-file bound is checked separately)."""

    def hang(signum, frame):
        raise TimeoutError(f"read still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _fuzz(seeds, n, seed, folder):
    outcomes, pairs, failures = Counter(), set(), []
    for fmt, kind, path in variants(seeds, n, seed, folder):
        with _alarm(4 * TIME_LIMIT_S):
            r = read_variant(path)
        outcomes[r["outcome"]] += 1
        pairs.add((fmt, kind))
        bad = []
        if r["outcome"] == "traceback":
            bad.append(r["message"].strip().splitlines()[-1][:300])
        if r["seconds"] > TIME_LIMIT_S:
            bad.append(f"took {r['seconds']:.1f} s")
        if r["memory_bytes"] > MEMORY_LIMIT:
            bad.append(f"used {r['memory_bytes'] / 2**20:.0f} MB")
        if bad:
            failures.append(f"{path.name} ({fmt}, {kind}): {'; '.join(bad)}")
        else:
            remove(path)
    return outcomes, pairs, failures


@pytest.fixture(scope="module")
def own_seeds(tmp_path_factory):
    return build_seeds(tmp_path_factory.mktemp("seeds"), sample=None, seed=0)


def test_the_seeds_read_cleanly(own_seeds):
    """The uncorrupted files are valid recordings with content (so the corruptions damage something)."""
    assert {s.format for s in own_seeds} == {"necviz", "aedat3", "aedat2", "rosbag1", "rosbag2", "hdf5", "rpg-text"}
    for s in own_seeds:
        r = read_variant(s.path)
        assert r["outcome"] == "clean", (s.path.name, r["message"])
        assert r["events"] > 0, s.path.name
        info = describe(s.path)
        assert not [w for w in info.warnings if "damage" in w], (s.path.name, info.warnings)


def test_corrupted_files_of_every_format_end_in_one_line_or_read_completely(own_seeds, tmp_path):
    n = len(own_seeds) * len(MUTATIONS) * 5  # every seed gets every mutation about 5 times
    outcomes, pairs, failures = _fuzz(own_seeds, n, 1234, tmp_path / "variants")
    assert not failures, f"{len(failures)} of {n} variants failed:\n" + "\n".join(failures[:10])
    formats = {s.format for s in own_seeds}
    for fmt in formats:  # every format met every byte-level mutation
        assert {k for f, k in pairs if f == fmt} >= set(MUTATIONS[:-2]), fmt
    # both outcomes occur: the damage is real, and harmless damage still reads
    assert outcomes["error"] > n // 4 and outcomes["clean"] > n // 20, outcomes


def test_corrupted_copies_of_the_real_davis346_sample(tmp_path):
    if not SAMPLE_AEDAT4.is_file():
        pytest.skip(f"the real AEDAT 4 sample is not here ({SAMPLE_AEDAT4})")
    seeds = [s for s in build_seeds(tmp_path / "seeds", seed=0) if s.format == "aedat4"]
    n = 9 * 12
    outcomes, pairs, failures = _fuzz(seeds, n, 99, tmp_path / "variants")
    assert not failures, f"{len(failures)} of {n} variants failed:\n" + "\n".join(failures[:10])
    assert outcomes["error"] > n // 4 and outcomes["clean"] > 0, outcomes


def test_a_non_utf8_aedat4_description_is_refused_before_the_decoder_sees_it(tmp_path):
    """aedat 2.3 aborts the whole process on such a header; the reader must stop it first."""
    if not SAMPLE_AEDAT4.is_file():
        pytest.skip(f"the real AEDAT 4 sample is not here ({SAMPLE_AEDAT4})")
    data = bytearray(SAMPLE_AEDAT4.read_bytes())
    at = data.index(b"<dv version")
    data[at + 1] = 0xC9  # a lead byte without its continuation byte
    bad = tmp_path / "bad_description.aedat4"
    bad.write_bytes(bytes(data))
    with pytest.raises(
        RecordingError, match=rf"bad_description\.aedat4: IOHeader description is not UTF-8.* at byte {at + 1}$"
    ):
        open_recording(bad)


# --------------------------------------------------------------------------- the one error path


class PanicException(BaseException):
    """Stands in for PyO3's panic type: a BaseException from module ``pyo3_runtime``."""


PanicException.__module__ = "pyo3_runtime"


def _patched_decoder(monkeypatch, after: int, exc: BaseException):
    """Make ``aedat.Decoder`` raise ``exc`` after ``after`` packets."""
    import aedat

    real = aedat.Decoder

    class Decoder:
        def __init__(self, path):
            self._d = real(path)
            self._n = 0

        def id_to_stream(self):
            return self._d.id_to_stream()

        def __iter__(self):
            return self

        def __next__(self):
            if self._n == after:
                raise exc
            self._n += 1
            return next(self._d)

    monkeypatch.setattr(aedat, "Decoder", Decoder)


def test_a_decoder_panic_becomes_a_one_line_error_after_the_packets_before_it(monkeypatch):
    if not SAMPLE_AEDAT4.is_file():
        pytest.skip(f"the real AEDAT 4 sample is not here ({SAMPLE_AEDAT4})")
    clean = sum(len(p) for p in open_recording(SAMPLE_AEDAT4) if isinstance(p, EventBatch))
    _patched_decoder(monkeypatch, 20, PanicException("called `Option::unwrap()` on a `None` value"))
    got = []
    with pytest.raises(RecordingError) as err:
        for p in open_recording(SAMPLE_AEDAT4):
            got.append(p)
    msg = str(err.value)
    assert "\n" not in msg and SAMPLE_AEDAT4.name in msg and "decoder panic" in msg and " at byte " in msg
    n = sum(len(p) for p in got if isinstance(p, EventBatch))
    assert 0 < n < clean  # what the first 20 packets held was delivered (the assembler was drained)


def test_keyboard_interrupt_is_not_mistaken_for_a_panic(monkeypatch):
    if not SAMPLE_AEDAT4.is_file():
        pytest.skip(f"the real AEDAT 4 sample is not here ({SAMPLE_AEDAT4})")
    _patched_decoder(monkeypatch, 5, KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        list(open_recording(SAMPLE_AEDAT4))


def test_an_h5py_error_mid_file_names_the_dataset_after_the_rows_before_it(tmp_path, monkeypatch):
    import h5py

    from necviz.drivers.recordings import hdf5

    rng = np.random.default_rng(3)
    n = 5000
    t = np.sort(rng.integers(0, 100_000, n))
    path = write_dsec(tmp_path / "events.h5", t, rng.integers(0, 32, n), rng.integers(0, 24, n), rng.integers(0, 2, n))
    monkeypatch.setattr(hdf5, "CHUNK", 1000)
    real = h5py.Dataset.__getitem__

    def getitem(self, key):
        if self.name == "/events/x" and isinstance(key, slice) and key.start == 3000:
            raise KeyError("Unable to synchronously open object (bad object header version number)")
        return real(self, key)

    monkeypatch.setattr(h5py.Dataset, "__getitem__", getitem)
    got = []
    with pytest.raises(RecordingError) as err:
        for p in open_recording(path):
            got.append(p)
    msg = str(err.value)
    assert msg.startswith(f"{path}: damaged or unreadable data (KeyError: ") and "\n" not in msg
    assert msg.endswith("at dataset /events/x [3000:4000]")
    ev = np.concatenate([p.events for p in got if isinstance(p, EventBatch)])
    assert np.array_equal(ev["t"], t[:3000])  # every row before the damaged slice, none invented
    info = describe(path)  # info shows the readable part and the damage as a warning
    assert info.events == 3000 and any("at dataset /events/x [3000:4000]" in w for w in info.warnings)


def test_a_bug_is_not_disguised_as_damage(tmp_path, monkeypatch):
    """NameError/AttributeError in a reader are bugs: they stay tracebacks (the CLI reports them)."""
    from necviz.drivers.recordings import text

    path = tmp_path / "events.txt"
    path.write_text("0.1 1 2 1\n0.2 3 4 0\n")

    def broken(rows):
        raise AttributeError("'NoneType' object has no attribute 'x'")

    monkeypatch.setattr(text, "_valid_events", broken)
    with pytest.raises(AttributeError):
        list(open_recording(path, sensor=None))


# ------------------------------------------------------------------ issue 23: bounded on any input


def test_hostile_files_and_paths_end_in_one_line_within_10_s_and_512_mb(tmp_path):
    """Every case of ``tests/hostile.py`` (files declaring more than they hold, decompression bombs,
    zero runs after valid data, pipes, devices, link loops, non-UTF-8 names, a decoder panic, outputs
    naming inputs) plus 36 corrupted AEDAT 3.1/2.0 and HDF5 files through ``replay``: each ends
    clean or in one line, within 10 s and 512 MB of growth, inputs byte-identical. Run in a child
    process with a 6 GB address-space cap, so a case that runs away cannot take the suite with it."""
    import json
    import resource
    import subprocess
    import sys
    from pathlib import Path

    from hostile import problems

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))

    out = tmp_path / "results.json"
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).with_name("hostile.py")), str(out), str(tmp_path / "work"), "36"],
        capture_output=True,
        text=True,
        errors="replace",
        timeout=600,
        preexec_fn=cap,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = json.loads(out.read_text())
    bad = [f"{r['name']}: {'; '.join(problems(r))}" for r in results if problems(r)]
    assert not bad, "\n".join(bad)
    groups = {r["group"] for r in results}
    assert groups == {"files", "paths", "replay"} and len(results) > 80
    outcomes = {r["outcome"] for r in results}
    assert outcomes == {"clean", "error"}  # both happen: the damage is real, valid input still works


def test_the_stderr_trap_drops_a_panics_text_and_passes_everything_else_on(capfd):
    import os

    from necviz.drivers.recordings.reader import StderrTrap

    trap = StderrTrap()
    with trap():
        os.write(2, b"a library's own note\n")
    with pytest.raises(PanicException):
        with trap():
            os.write(2, b"thread '<unnamed>' panicked at src/lib.rs:1:1:\nstack backtrace:\n   0: ...\n")
            raise PanicException("index out of bounds")
    with trap(discard=True):
        os.write(2, b"libpng error: bad adaptive filter value\n")
    trap.close()
    assert capfd.readouterr().err == "a library's own note\n"


def test_declared_sizes_are_checked_against_what_the_file_holds(tmp_path):
    import h5py

    p = tmp_path / "sparse.h5"
    with h5py.File(p, "w") as f:
        g = f.create_group("events")
        for k, dt in zip("txyp", ("i8", "u2", "u2", "u1"), strict=True):
            g.create_dataset(k, shape=(1 << 38,), dtype=dt, chunks=(1 << 16,))
    assert p.stat().st_size < 10_000
    with pytest.raises(RecordingError, match=r"/events/t declares 274,877,906,944 entries .* holds 0 bytes"):
        open_recording(p)


def test_timestamps_that_never_advance_are_damage_not_a_memory_leak(tmp_path):
    """8 M events at t = 0 (zeros decompressed from a tiny file) end in one line instead of being held."""
    from necviz.drivers.recordings.reader import MAX_HELD_EVENTS

    n = MAX_HELD_EVENTS + (1 << 18)
    z = np.zeros(n, np.int64)
    path = write_dsec(tmp_path / "zeros.h5", z, z, z, z)
    got = 0
    with pytest.raises(RecordingError, match="without the stream's time advancing"):
        for p in open_recording(path):
            got += len(p) if isinstance(p, EventBatch) else 0
    assert got <= n


def test_a_run_of_zero_bytes_in_a_text_file_is_damage_at_its_offset(tmp_path):
    p = tmp_path / "events.txt"
    with open(p, "wb") as f:
        f.write(b"0.1 1 2 1\n0.2 3 4 0\n")
        f.truncate(64 << 20)  # sparse: 64 MB of zeros after two lines
    got = []
    with pytest.raises(RecordingError, match=r"a run of zero bytes in events.txt .* at byte 20$"):
        for pk in open_recording(p):
            got.append(pk)
    assert sum(len(pk) for pk in got if isinstance(pk, EventBatch)) == 2  # the two lines before it


def test_a_named_pipe_is_refused_unless_asked_for_then_read_through_a_copy(tmp_path):
    import os
    import threading

    if not SAMPLE_AEDAT4.is_file():
        pytest.skip(f"the real AEDAT 4 sample is not here ({SAMPLE_AEDAT4})")
    fifo = tmp_path / "live.aedat4"
    os.mkfifo(fifo)
    with pytest.raises(RecordingError, match="a named pipe, not a regular file.*--pipe-timeout"):
        open_recording(fifo)
    with pytest.raises(RecordingError, match="no data from the named pipe within 0.3 s"):
        open_recording(fifo, pipe_timeout_s=0.3)

    def writer():
        with open(fifo, "wb") as f:
            f.write(SAMPLE_AEDAT4.read_bytes())

    threading.Thread(target=writer, daemon=True).start()
    rec = open_recording(fifo, pipe_timeout_s=10)
    copy = rec.path
    n = sum(len(p) for p in rec if isinstance(p, EventBatch))
    rec.close()
    assert n == sum(len(p) for p in open_recording(SAMPLE_AEDAT4) if isinstance(p, EventBatch))
    assert not copy.exists()  # the temporary copy goes with the recording
