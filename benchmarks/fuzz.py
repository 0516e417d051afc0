#!/usr/bin/env python
"""Hostile input for the DAVIS decoder, every recording reader and the command line (issues 14, 23):
counts, not timings.

Four parts, each run in worker processes watched by this one, so that a hard crash (a segfault, an
abort inside a native library) or a hang is counted against the input that caused it and the run
goes on with a fresh worker:

* **decoder** — ``--decoder-inputs`` word streams for :class:`~necviz.drivers.davis.DavisDecoder`,
  each split into transfers at random byte offsets: uniform random words; words biased towards the
  meaningful codes (specials 0..17, small addresses, time words, IMU/ROI bytes); valid encoder
  streams (events, frames — some exposed for less than 1 µs —, IMU, triggers, resets, long gaps)
  with one bit flipped; the same with heavier damage (many flips, random words, deleted, duplicated
  or zeroed spans, truncation); and two valid streams spliced at random points. An input is *clean*
  when the decoder returns and every invariant holds: no event off the sensor; events and exposure
  markers together in time order; markers paired, each end after its start; every frame right after
  its end marker; for a single flipped bit, at most one event more than the clean stream. A broken
  invariant or an exception is counted as a *traceback*.
* **files** — ``--file-variants`` corrupted recordings of every format (``tests/fuzz_corpus.py``:
  the project's own writers plus the real DAVIS346 AEDAT 4 sample when ``../shared/data`` has it),
  each read completely (``open_recording`` + iteration, then ``describe``). Outcomes: *clean* (read
  to the end), *one-line error* (a NecvizError of one line naming the file) or *traceback*
  (anything else); reads over the per-file time bound are killed and counted as *hangs*; the peak
  memory of each read (Linux VmHWM growth) is checked against ``--memory-limit-mb``.
* **replay** — ``--replay-variants`` corrupted recordings of every format through ``necviz replay``
  (the whole dashboard path: P-TEDI, telemetry, the Rerun sink, a ``--save`` file), as a user runs
  it (``tests/hostile.py``: the command line in the worker, file descriptor 2 captured). Outcomes:
  *clean* (exit 0, nothing on standard error), *one-line error* (exit 2, one line) or *traceback*
  (exit 3, several lines, a Rust panic message …); the peak memory and time bounds as above.
* **hostile** — every case of ``tests/hostile.py``: files that declare more than they hold, gzip
  bombs, gigabytes of zeros after valid data, pipes and devices under recording names, link loops,
  non-UTF-8 names, the byte that makes the AEDAT 4 decoder panic, and the path cases (an output
  naming an input directly or through a link, a folder, ``/dev/null`` …). A case passes when its
  outcome is the one expected, within the bounds, with every input byte-identical; anything else
  is counted as a *traceback* (with the case named in the examples).

Every input is a pure function of ``--seed`` and its index (printed with each failure), so any
failure can be reproduced alone. Prints a table and writes JSON (``benchmarks/results/fuzz.json``).

usage: python benchmarks/fuzz.py [--decoder-inputs 1000000] [--file-variants 10000]
                                 [--replay-variants 5000] [--no-hostile] [--seed 0] [--json PATH]
                                 [--workers 2] [--time-limit 10] [--memory-limit-mb 512]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import shutil
import sys
import tempfile
import time
from collections import Counter
from multiprocessing.connection import wait
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))  # fuzz_corpus, format_writers

DECODER_TASK = 2000  # decoder inputs per task sent to a worker
FILE_TASK = 20  # file variants per task
REPLAY_TASK = 10  # replays per task
HOSTILE_TASK = 4  # hostile cases per task
EXAMPLES = 20  # failures kept (with their index) in the JSON


# =============================================================================== decoder inputs
SIZES = ((4, 3), (8, 6), (17, 11), (40, 30), (346, 260))


def _valid_stream(rng, w, h):
    """A valid DAVIS word stream (``StreamEncoder``): event runs, frames with events inside their
    exposure (some exposures shorter than 1 µs), IMU samples, triggers, timestamp resets, long gaps."""
    import numpy as np

    from necviz.core.events import EVENT_DTYPE
    from necviz.drivers.davis import StreamEncoder

    enc = StreamEncoder(aps_orientation=int(rng.integers(0, 8)), always_y=bool(rng.integers(0, 2)))
    parts = [enc.timestamp_reset()]
    t = int(rng.integers(0, 3000))

    def events(t0, t1, n):
        ev = np.empty(n, EVENT_DTYPE)
        ev["t"] = np.sort(rng.integers(t0, t1 + 1, n))
        ev["x"] = rng.integers(0, w, n)
        ev["y"] = rng.integers(0, h, n)
        ev["p"] = rng.choice(np.array([-1, 1], np.int8), n)
        parts.append(enc.events(ev))

    for _ in range(int(rng.integers(2, 8))):
        kind = rng.choice(6, p=[0.3, 0.35, 0.1, 0.1, 0.1, 0.05])
        if kind == 0:
            t1 = t + int(rng.integers(0, 40_000))
            events(t, t1, int(rng.integers(0, 150)))
            t = t1
        elif kind == 1:
            c0, c1 = sorted(int(v) for v in rng.integers(0, w, 2))
            r0, r1 = sorted(int(v) for v in rng.integers(0, h, 2))
            fh, fw = r1 - r0 + 1, c1 - c0 + 1
            es = t + int(rng.integers(0, 30))
            ee = es + int(rng.choice([0, 1, int(rng.integers(2, 20_000))]))  # 0: sub-µs exposure
            fe = ee + int(rng.integers(0, 2000))
            parts += [
                enc.frame_start(t, (c0, r0, c1, r1), int(rng.integers(0, 1 << 30))),
                enc.readout(rng.integers(300, 1024, (fh, fw)), False),
                enc.special(es, 14),
            ]
            if ee == es:
                parts.append(enc.special(ee, 15))
                events(es, es, int(rng.integers(0, 4)))  # events in the same µs, after the end word
            else:
                events(es, ee, int(rng.integers(0, 60)))
                parts.append(enc.special(ee, 15))
            events(ee, fe, int(rng.integers(0, 20)))
            parts += [enc.readout(rng.integers(0, 1024, (fh, fw)), True), enc.special(fe, 10)]
            t = fe
        elif kind == 2:
            parts.append(
                enc.imu(
                    t,
                    [int(v) for v in rng.integers(-32768, 32768, 7)],
                    int(rng.integers(0, 4)),
                    int(rng.integers(0, 4)),
                    int(rng.integers(1, 8)),
                )
            )
        elif kind == 3:
            parts.append(
                enc.trigger(
                    t,
                    str(
                        rng.choice(
                            [
                                "external_rising",
                                "external_falling",
                                "external_pulse",
                                "generator_rising",
                                "generator_falling",
                            ]
                        )
                    ),
                )
            )
        elif kind == 4:
            t += int(rng.choice([32768, 65536 * 3, 4095 * 32768 + 5]))
        else:
            parts.append(enc.timestamp_reset())
            t = int(rng.integers(0, 100))
        t += int(rng.integers(0, 3))
    return np.concatenate(parts)


def _biased_words(rng, n):
    import numpy as np

    kind = rng.integers(0, 4, n)
    code = rng.integers(0, 8, n)
    small = rng.integers(0, 25, n)
    out = rng.integers(0, 1 << 16, n)
    out = np.where(kind == 1, (code << 12) | small, out)
    out = np.where(kind == 2, 0x5000 | (rng.integers(0, 4, n) << 8) | rng.integers(0, 256, n), out)
    out = np.where(kind == 3, 0x8000 | rng.integers(0, 0x8000, n), out)
    return out.astype(np.uint16)


def _damage(rng, words):
    import numpy as np

    w = words.copy()
    for _ in range(int(rng.integers(1, 6))):
        op = int(rng.integers(0, 5))
        n = w.size
        if n == 0:
            break
        i = int(rng.integers(0, n))
        if op == 0:
            k = rng.integers(0, n, int(rng.integers(1, 30)))
            w[k] ^= np.uint16(1) << rng.integers(0, 16, k.size).astype(np.uint16)
        elif op == 1:
            w[i : i + 20] = rng.integers(0, 1 << 16, w[i : i + 20].size).astype(np.uint16)
        elif op == 2:
            w = np.concatenate([w[:i], w[i + int(rng.integers(1, 200)) :]])
        elif op == 3:
            j = min(n, i + int(rng.integers(1, 200)))
            w = np.concatenate([w[:j], w[i:j], w[j:]])
        else:
            w = w[:i]
    return w


class DecoderFuzz:
    """Inputs and checks of the decoder part (one instance per worker)."""

    def __init__(self, seed: int, pool: int = 48):
        import numpy as np

        from necviz.drivers.davis import DavisDecoder, DecoderOptions

        self.np, self.Decoder, self.Format = np, DavisDecoder, DecoderOptions
        self.seed = seed
        rng = np.random.default_rng([seed, 7])
        self.pool = []
        for k in range(pool):
            w, h = SIZES[k % 4]
            words = _valid_stream(rng, w, h)
            packets = self._decode(words.tobytes(), w, h, [])
            problem = self.check(packets, w, h)
            assert problem is None, f"valid stream {k}: {problem}"
            n = sum(p.size for p in packets if isinstance(p, np.ndarray))
            self.pool.append((w, h, words, n))

    def _decode(self, raw: bytes, w, h, cuts):
        dec = self.Decoder(self.Format(w, h))
        out, prev = [], 0
        for c in sorted(set(cuts)) + [len(raw)]:
            out += dec.decode(raw[prev:c])
            prev = c
        return out + dec.finish()

    def check(self, packets, w, h):
        """None if every invariant holds, else what is wrong."""
        from necviz.core.frames import ExposureMarker, Frame

        np = self.np
        last = -(1 << 62)
        open_start = None
        last_pair = None
        for p in packets:
            if isinstance(p, np.ndarray):
                if p.size == 0:
                    continue
                t = p["t"]
                if int(t[0]) < last or (p.size > 1 and bool(np.any(t[1:] < t[:-1]))):
                    return "time runs backwards (events)"
                if int(p["x"].max()) >= w or int(p["y"].max()) >= h:
                    return "event off the sensor"
                if not bool(np.all((p["p"] == 1) | (p["p"] == -1))):
                    return "polarity not +-1"
                last = int(t[-1])
            elif isinstance(p, ExposureMarker):
                if p.t_us < last:
                    return f"{p.kind} marker at {p.t_us} after events at {last}"
                last = p.t_us
                if p.kind == "start":
                    if open_start is not None:
                        return "two starts without an end"
                    open_start = p.t_us
                else:
                    if open_start is None or p.t_us <= open_start:
                        return "end without a start, or not after it"
                    last_pair, open_start = (open_start, p.t_us), None
            elif isinstance(p, Frame):
                if last_pair != (p.exposure_start_us, p.exposure_end_us):
                    return "frame does not follow its end marker"
                if p.image.shape != (h, w):
                    return "frame of the wrong shape"
                last_pair = None
        if open_start is not None:
            return "exposure left open after finish()"
        return None

    def run(self, i: int):
        """Input ``i``: returns (kind, problem or None)."""
        np = self.np
        rng = np.random.default_rng([self.seed, 1, i])
        kind = i % 5
        flipped_from = None
        if kind == 0:
            w, h = SIZES[int(rng.integers(0, len(SIZES)))]
            raw = rng.integers(0, 256, int(rng.integers(0, 6000)), dtype=np.uint8).tobytes()
        elif kind == 1:
            w, h = SIZES[int(rng.integers(0, len(SIZES)))]
            raw = _biased_words(rng, int(rng.integers(0, 3000))).tobytes()
        elif kind == 2:
            w, h, words, n_clean = self.pool[int(rng.integers(0, len(self.pool)))]
            words = words.copy()
            k = int(rng.integers(0, words.size))
            words[k] ^= np.uint16(1 << int(rng.integers(0, 16)))
            raw, flipped_from = words.tobytes(), n_clean
        elif kind == 3:
            w, h, words, _ = self.pool[int(rng.integers(0, len(self.pool)))]
            raw = _damage(rng, words).tobytes()
        else:
            a = self.pool[int(rng.integers(0, len(self.pool)))]
            b = self.pool[int(rng.integers(0, len(self.pool)))]
            w, h = a[0], a[1]
            wa, wb = a[2], b[2]
            raw = np.concatenate(
                [wa[: int(rng.integers(0, wa.size + 1))], wb[int(rng.integers(0, wb.size + 1)) :]]
            ).tobytes()
        cuts = [int(c) for c in rng.integers(0, len(raw) + 1, int(rng.integers(0, 4)))]
        try:
            packets = self._decode(raw, w, h, cuts)
        except Exception as exc:  # noqa: BLE001 - counted
            return kind, f"{type(exc).__name__}: {exc}"
        problem = self.check(packets, w, h)
        if problem is None and flipped_from is not None:
            n = sum(p.size for p in packets if isinstance(p, np.ndarray))
            if n > flipped_from + 1:
                problem = f"one flipped bit added {n - flipped_from} events"
        return kind, problem


# =============================================================================== workers
def _worker(conn, cur, cfg, part):
    """Run tasks ``(part, start, stop)`` sent by the parent; ``cur`` holds the input being processed.

    Before reporting ready, the worker warms up outside the timed inputs: imports, Numba caches,
    the decoder's pool of valid streams, one clean read of every seed file."""
    log = open(Path(cfg["tmp"]) / f"worker-{os.getpid()}.log", "w")
    os.dup2(log.fileno(), 2)  # OpenCV/libpng/Rust chatter about damaged input
    os.dup2(log.fileno(), 1)  # what the commands of the replay and hostile parts print
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    from fuzz_corpus import Seed, VariantMaker, read_variant, remove

    dec = maker = cases = None
    cur.value = -1
    work = Path(cfg["tmp"]) / f"{part}-{os.getpid()}"
    if part == "decoder":
        dec = DecoderFuzz(cfg["seed"])
    elif part == "hostile":
        from fuzz_corpus import SAMPLE_AEDAT4
        from hostile import build_cases

        seeds = [Seed(s["format"], Path(s["path"]), tuple(s["members"])) for s in cfg["seeds"]]
        cases = build_cases(work / "cases", seeds, SAMPLE_AEDAT4)
        os.chdir(work)
        from hostile import Case, run_case

        for argv in (["info", str(seeds[0].path)], ["replay", str(seeds[0].path), "--save", str(work / "w.rrd")]):
            run_case(Case("warm-up", argv))  # imports and caches outside the measured cases
        remove(work / "w.rrd")
    else:
        seeds = [Seed(s["format"], Path(s["path"]), tuple(s["members"])) for s in cfg["seeds"]]
        maker = VariantMaker(seeds, cfg["seed"], work / "variants")
        for s in seeds:
            read_variant(s.path)
        if part == "replay":
            from hostile import Case, run_case

            run_case(Case("warm-up", ["replay", str(seeds[0].path), "--save", str(work / "warm.rrd")]))
            remove(work / "warm.rrd")
    conn.send(("ready", None))
    while True:
        task = conn.recv()
        if task is None:
            return
        part, start, stop = task
        res = {
            "part": part,
            "start": start,
            "stop": stop,
            "outcomes": Counter(),
            "by": {},
            "examples": [],
            "max_seconds": 0.0,
            "max_memory": 0,
            "over_memory": 0,
        }
        for i in range(start, stop):
            cur.value = i
            if (part, i) in cfg["inject"]:  # checking the harness itself: a hard crash / a hang here
                if cfg["inject"][(part, i)] == "crash":
                    os.abort()
                time.sleep(1e6)
            if part in ("replay", "hostile"):
                from hostile import Case, problems, run_case

                if part == "replay":
                    fmt, mutation, path = maker.make(i)
                    rrd = work / f"r{i}.rrd"
                    case = Case(f"{fmt} {mutation}", ["replay", str(path), "--save", str(rrd)], ("clean", "error"))
                else:
                    case = cases[i]
                    fmt, mutation, path = case.group, case.name, None
                r = run_case(case, cfg["time_limit"])
                wrong = [p for p in problems(r, cfg["time_limit"], cfg["memory_limit"] / 2**20) if "grew" not in p]
                outcome = r["outcome"]
                if outcome in ("clean", "error") and wrong:
                    outcome = "traceback"  # the wrong outcome, a changed input or a leftover output
                over = r["memory_mb"] * 2**20 > cfg["memory_limit"]
                res["over_memory"] += over
                res["max_seconds"] = max(res["max_seconds"], r["seconds"])
                res["max_memory"] = max(res["max_memory"], r["memory_mb"] * 2**20)
                by = res["by"].setdefault(fmt, Counter())
                by[outcome] += 1
                if (outcome not in ("clean", "error") or over or wrong) and len(res["examples"]) < EXAMPLES:
                    res["examples"].append(
                        {
                            "index": i,
                            "case": case.name,
                            "memory_mb": round(r["memory_mb"], 1),
                            "seconds": round(r["seconds"], 2),
                            "problem": ("; ".join(wrong) or r["stderr"].strip()[-300:] or outcome)[:300],
                        }
                    )
                if path is not None:
                    remove(path)
                for leftover in work.glob("r*.rrd"):
                    remove(leftover)
                res["outcomes"][outcome] += 1
                continue
            if part == "decoder":
                kind, problem = dec.run(i)
                outcome = "clean" if problem is None else "traceback"
                by = res["by"].setdefault(f"kind {kind}", Counter())
                by[outcome] += 1
                if problem is not None and len(res["examples"]) < EXAMPLES:
                    res["examples"].append({"index": i, "kind": kind, "problem": problem[:300]})
            else:
                fmt, mutation, path = maker.make(i)
                r = read_variant(path)
                outcome = r["outcome"]
                if r["memory_bytes"] > cfg["memory_limit"]:
                    res["over_memory"] += 1
                    outcome = "traceback" if outcome == "clean" else outcome
                res["max_seconds"] = max(res["max_seconds"], r["seconds"])
                res["max_memory"] = max(res["max_memory"], r["memory_bytes"])
                by = res["by"].setdefault(fmt, Counter())
                by[outcome] += 1
                if (outcome == "traceback" or r["memory_bytes"] > cfg["memory_limit"]) and len(
                    res["examples"]
                ) < EXAMPLES:
                    res["examples"].append(
                        {
                            "index": i,
                            "format": fmt,
                            "mutation": mutation,
                            "memory_mb": round(r["memory_bytes"] / 2**20, 1),
                            "problem": r["message"].strip().splitlines()[-1][:300],
                        }
                    )
                remove(path)
            res["outcomes"][outcome] += 1
        cur.value = -2
        conn.send(("done", res))


class Pool:
    """Worker processes with crash and hang detection (see the module docstring)."""

    def __init__(self, n: int, cfg: dict, time_limit: float, part: str):
        self.ctx = mp.get_context("spawn")
        self.cfg, self.time_limit, self.part = cfg, time_limit, part
        self.workers = [self._spawn() for _ in range(n)]

    def _spawn(self) -> dict:
        parent, child = self.ctx.Pipe()
        cur = self.ctx.Value("q", -1, lock=False)
        proc = self.ctx.Process(target=_worker, args=(child, cur, self.cfg, self.part), daemon=True)
        proc.start()
        child.close()
        return {
            "proc": proc,
            "conn": parent,
            "cur": cur,
            "task": None,
            "seen": -1,
            "since": time.monotonic(),
            "ready": False,
        }

    def _kill(self, w) -> None:
        if w["proc"].is_alive():
            w["proc"].kill()
        w["proc"].join()
        w["conn"].close()

    def run(self, tasks: list, merge, fail, progress=None) -> None:
        """Run every task; ``merge(result)`` per finished task, ``fail(part, index, what)`` per crash/hang,
        ``progress(finished tasks)`` now and then."""
        tasks = list(tasks)
        finished, shown = 0, time.monotonic()
        while tasks or any(w["task"] for w in self.workers):
            if progress is not None and time.monotonic() - shown > 10:
                progress(finished)
                shown = time.monotonic()
            for w in self.workers:
                if w["ready"] and w["task"] is None and tasks:
                    w["task"] = tasks.pop(0)
                    w["seen"], w["since"] = -1, time.monotonic()
                    w["conn"].send(w["task"])
            ready = wait([w["conn"] for w in self.workers], timeout=0.2)
            now = time.monotonic()
            for k, w in enumerate(self.workers):
                broken = None
                if w["conn"] in ready:
                    try:
                        msg, payload = w["conn"].recv()
                    except (EOFError, OSError):
                        broken = "crash"
                    else:
                        if msg == "ready":
                            w["ready"] = True
                        else:
                            merge(payload)
                            w["task"] = None
                            finished += 1
                        continue
                if broken is None and not w["proc"].is_alive():
                    broken = "crash"
                if broken is None and w["task"] is not None:
                    i = w["cur"].value
                    if i != w["seen"]:
                        w["seen"], w["since"] = i, now
                    elif i >= 0 and now - w["since"] > self.time_limit:
                        broken = "hang"
                if broken is None and not w["ready"] and now - w["since"] > 600:
                    raise RuntimeError("a fuzz worker did not start within 10 minutes")
                if broken is None:
                    continue
                task, i = w["task"], w["cur"].value
                self._kill(w)
                if task is None or i < 0:
                    if task is not None:
                        tasks.insert(0, task)
                    if not w["ready"]:
                        raise RuntimeError("a fuzz worker failed while starting (see its log)")
                else:
                    part, start, stop = task
                    fail(part, i, broken)
                    # the inputs before i are run again (their results were lost with the worker)
                    if start < i:
                        tasks.insert(0, (part, start, i))
                    if i + 1 < stop:
                        tasks.insert(0, (part, i + 1, stop))
                self.workers[k] = self._spawn()

    def close(self) -> None:
        for w in self.workers:
            try:
                w["conn"].send(None)
            except (OSError, ValueError):
                pass
        for w in self.workers:
            w["proc"].join(timeout=10)
            if w["proc"].is_alive():
                w["proc"].kill()


# =============================================================================== main
def run(
    decoder_inputs: int,
    file_variants: int,
    seed: int,
    workers: int,
    time_limit: float,
    memory_limit_mb: float,
    out=sys.stdout,
    inject: dict | None = None,
    replay_variants: int = 0,
    hostile: bool = False,
) -> dict:
    """Run both parts (see the module docstring) and print the table; returns the JSON-ready result.

    ``inject`` maps ``(part, index)`` to ``"crash"`` or ``"hang"`` (to check that the harness counts them)."""
    from fuzz_corpus import SAMPLE_AEDAT4, build_seeds

    tmp = tempfile.mkdtemp(prefix="necviz-fuzz-")
    try:
        seeds = build_seeds(Path(tmp) / "seeds", seed=seed)
        cfg = {
            "seed": seed,
            "tmp": tmp,
            "memory_limit": memory_limit_mb * 2**20,
            "time_limit": time_limit,
            "inject": dict(inject or {}),
            "seeds": [{"format": s.format, "path": str(s.path), "members": list(s.members)} for s in seeds],
        }
        parts = {}
        n_hostile = 0
        if hostile:
            from hostile import build_cases

            n_hostile = len(build_cases(Path(tmp) / "count", seeds, SAMPLE_AEDAT4))
            shutil.rmtree(Path(tmp) / "count", ignore_errors=True)
        for part, n, size in (
            ("decoder", decoder_inputs, DECODER_TASK),
            ("files", file_variants, FILE_TASK),
            ("replay", replay_variants, REPLAY_TASK),
            ("hostile", n_hostile, HOSTILE_TASK),
        ):
            if n <= 0:
                continue
            acc = {
                "inputs": n,
                "outcomes": Counter(),
                "by": {},
                "hangs": 0,
                "crashes": 0,
                "examples": [],
                "max_seconds": 0.0,
                "max_memory_mb": 0.0,
                "over_memory": 0,
            }

            def merge(res, acc=acc):
                acc["outcomes"].update(res["outcomes"])
                for k, c in res["by"].items():
                    acc["by"].setdefault(k, Counter()).update(c)
                acc["examples"] += res["examples"][: max(0, EXAMPLES - len(acc["examples"]))]
                acc["max_seconds"] = max(acc["max_seconds"], res["max_seconds"])
                acc["max_memory_mb"] = max(acc["max_memory_mb"], res["max_memory"] / 2**20)
                acc["over_memory"] += res["over_memory"]

            def fail(part, i, what, acc=acc):
                acc["hangs" if what == "hang" else "crashes"] += 1
                if len(acc["examples"]) < EXAMPLES:
                    acc["examples"].append({"index": i, "problem": what})
                print(f"\n  {part} input {i}: {what}", file=out, flush=True)

            t0 = time.perf_counter()
            pool = Pool(workers, cfg, time_limit, part)
            ntasks = (n + size - 1) // size

            def progress(done, part=part, ntasks=ntasks, t0=t0):
                print(
                    f"\r  {part}: {done}/{ntasks} tasks, {time.perf_counter() - t0:.0f} s", end="", file=out, flush=True
                )

            try:
                pool.run([(part, a, min(a + size, n)) for a in range(0, n, size)], merge, fail, progress)
            finally:
                pool.close()
            print(f"\r  {part}: done in {time.perf_counter() - t0:.0f} s" + " " * 20, file=out, flush=True)
            acc["seconds"] = time.perf_counter() - t0
            done = sum(acc["outcomes"].values())
            assert done + acc["hangs"] + acc["crashes"] == n, (done, acc["hangs"], acc["crashes"], n)
            parts[part] = acc
        result = {
            "command": (
                f"python benchmarks/fuzz.py --decoder-inputs {decoder_inputs} --file-variants {file_variants} "
                f"--replay-variants {replay_variants}{'' if hostile else ' --no-hostile'} --seed {seed} "
                f"--workers {workers} --time-limit {time_limit:g} --memory-limit-mb {memory_limit_mb:g}"
            ),
            "seed": seed,
            "workers": workers,
            "time_limit_s": time_limit,
            "memory_limit_mb": memory_limit_mb,
            "aedat4_sample": SAMPLE_AEDAT4.is_file(),
            "formats": sorted({s.format for s in seeds}),
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
            "parts": {
                k: {**v, "outcomes": dict(v["outcomes"]), "by": {a: dict(b) for a, b in v["by"].items()}}
                for k, v in parts.items()
            },
        }
        _table(result, out)
        return result
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _table(result: dict, out) -> None:
    rows = [
        (
            "part",
            "inputs",
            "clean",
            "one-line errors",
            "tracebacks",
            "hangs",
            "crashes",
            "over memory",
            "peak memory",
            "slowest",
            "time",
        )
    ]
    for name, p in result["parts"].items():
        o = p["outcomes"]
        tb = o.get("traceback", 0) + o.get("hang", 0)
        rows.append(
            (
                name,
                f"{p['inputs']:,}",
                f"{o.get('clean', 0):,}",
                "-" if name == "decoder" else f"{o.get('error', 0):,}",
                f"{tb:,}",
                f"{p['hangs']:,}",
                f"{p['crashes']:,}",
                "-" if name == "decoder" else f"{p['over_memory']:,}",
                "-" if name == "decoder" else f"{p['max_memory_mb']:.0f} MB",
                "-" if name == "decoder" else f"{p['max_seconds']:.2f} s",
                f"{p['seconds']:.0f} s",
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    print(file=out)
    for r in rows:
        print(
            "  " + "  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True))),
            file=out,
        )
    for part in ("files", "replay", "hostile"):
        p = result["parts"].get(part)
        if not p:
            continue
        print(
            f"\n  {part}: slowest {p['max_seconds']:.2f} s, largest peak memory growth "
            f"{p['max_memory_mb']:.0f} MB, {p['over_memory']} over the limit",
            file=out,
        )
        for fmt, c in sorted(p["by"].items()):
            print(
                f"    {fmt:9s} {sum(c.values()):6,} {'cases' if part == 'hostile' else 'variants'}: "
                f"{c.get('clean', 0):6,} clean, {c.get('error', 0):6,} one-line errors, "
                f"{c.get('traceback', 0) + c.get('hang', 0):,} tracebacks",
                file=out,
            )
    for name, p in result["parts"].items():
        for ex in p["examples"][:5]:
            print(f"  {name} example: {ex}", file=out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--decoder-inputs", type=int, default=1_000_000)
    ap.add_argument("--file-variants", type=int, default=10_000)
    ap.add_argument("--replay-variants", type=int, default=5_000)
    ap.add_argument("--no-hostile", dest="hostile", action="store_false", help="skip the hostile cases")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=max(1, min(os.cpu_count() or 1, 2)))
    ap.add_argument("--time-limit", type=float, default=10.0, help="seconds per input before it is over the bound")
    ap.add_argument("--memory-limit-mb", type=float, default=512.0)
    ap.add_argument("--json", default=str(HERE / "results" / "fuzz.json"))
    ap.add_argument(
        "--inject",
        action="append",
        default=[],
        metavar="PART:INDEX:crash|hang",
        help="make input INDEX of PART (decoder/files) crash or hang, to check the harness",
    )
    a = ap.parse_args(argv)
    if a.decoder_inputs < 0 or a.file_variants < 0 or a.workers < 1 or a.time_limit <= 0:
        ap.error("counts must be >= 0, workers >= 1 and the time limit > 0")
    inject = {}
    for spec in a.inject:
        part, _, rest = spec.partition(":")
        index, _, what = rest.partition(":")
        if (
            part not in ("decoder", "files", "replay", "hostile")
            or not index.isdigit()
            or what not in ("crash", "hang")
        ):
            ap.error(f"--inject wants PART:INDEX:crash|hang, got {spec!r}")
        inject[(part, int(index))] = what
    if a.replay_variants < 0:
        ap.error("counts must be >= 0")
    res = run(
        a.decoder_inputs,
        a.file_variants,
        a.seed,
        a.workers,
        a.time_limit,
        a.memory_limit_mb,
        inject=inject,
        replay_variants=a.replay_variants,
        hostile=a.hostile,
    )
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        with open(a.json, "w") as f:
            json.dump(res, f, indent=2)
        print(f"\n  wrote {a.json}")
    bad = sum(p["outcomes"].get("traceback", 0) + p["hangs"] + p["crashes"] for p in res["parts"].values())
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
