"""Hostile inputs and paths for ``tests/test_fuzz_files.py`` and ``benchmarks/fuzz.py`` (issue 23).

:func:`build_cases` writes every case into a folder: files that declare far more than they hold
(an HDF5 of 3 kB declaring 2^38 events, gzip bombs), runs of zero bytes after valid data (sparse
files of gigabytes, cheap to make), named pipes and devices under recording names, a symbolic link
loop, non-UTF-8 file names of valid recordings, a sensor larger than any camera, the AEDAT 4
sample with one byte that makes the Rust decoder panic — and path cases, where an output names an
input (directly, through a symbolic or hard link), a folder, a device or a file where a folder should be.

:func:`run_case` runs one case through the command line in this process, the way a user would
(``necviz info`` / ``replay`` / ``compare`` …), with standard error (file descriptor 2, so Rust and
C libraries included) captured, and classifies it:

* ``clean``: exit 0 (valid input, or damage shown as a warning by ``info``);
* ``error``: exit 2 with exactly one line ``necviz: error: …`` on standard error;
* ``traceback``: anything else (exit 3, several lines, a panic message …).

It records the wall time and the growth of the peak resident set (Linux ``VmHWM``, reset before
the case) and checks that every file the case must not touch is byte-identical afterwards.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: bytes of the AEDAT 4 sample that make the ``aedat`` decoder panic / warn (found by mutation)
PANIC_BYTE = (100412, 247)
WARN_BYTE = (112327, 232)


@dataclass
class Case:
    """One hostile invocation: ``argv`` for ``necviz``; ``expect`` the outcomes allowed; ``keep`` files
    that must come out byte-identical; ``absent`` paths that must not exist afterwards."""

    name: str
    argv: list
    expect: tuple = ("error",)
    keep: list = field(default_factory=list)
    absent: list = field(default_factory=list)
    group: str = "files"


def _sparse(path: Path, head: bytes, total: int) -> Path:
    """``head`` followed by zero bytes up to ``total`` bytes (a sparse file: no disk space used)."""
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(total)
    return path


def _hdf5_cases(folder: Path) -> list[Case]:
    import h5py

    out = []
    p = folder / "declares_2e38.h5"
    with h5py.File(p, "w") as f:
        g = f.create_group("events")
        for k, dt in zip("txyp", ("i8", "u2", "u2", "u1"), strict=True):
            g.create_dataset(k, shape=(1 << 38,), dtype=dt, chunks=(1 << 16,))
    out.append(Case("hdf5: 3 kB declaring 2^38 events", ["info", str(p)]))
    out.append(Case("hdf5: 3 kB declaring 2^38 events (replay)", ["replay", str(p), "--save", str(folder / "a.rrd")]))
    n = 100_000_000 // 8
    p = folder / "bomb_one_chunk.h5"
    with h5py.File(p, "w") as f:
        g = f.create_group("events")
        for k, dt in zip("txyp", ("i8", "u2", "u2", "u1"), strict=True):
            g.create_dataset(k, data=np.zeros(n, dt), chunks=(n,), compression="gzip", compression_opts=1)
    out.append(Case("hdf5: gzip bomb in one 100 MB chunk", ["info", str(p)]))
    p = folder / "bomb_zeros.h5"
    n = 120_000_000 // 13
    with h5py.File(p, "w") as f:
        g = f.create_group("events")
        for k, dt in zip("txyp", ("i8", "u2", "u2", "u1"), strict=True):
            g.create_dataset(k, data=np.zeros(n, dt), chunks=(1 << 18,), compression="gzip", compression_opts=1)
    out.append(Case("hdf5: 120 MB of zero events from 0.5 MB", ["info", str(p)], ("clean", "error")))
    out.append(Case("hdf5: zero events bomb (replay)", ["replay", str(p), "--save", str(folder / "b.rrd")]))
    p = folder / "huge_sensor.h5"
    with h5py.File(p, "w") as f:
        f.attrs["width"], f.attrs["height"] = 65535, 65535
        g = f.create_group("events")
        for k, dt in zip("txyp", ("i8", "u2", "u2", "u1"), strict=True):
            g.create_dataset(k, data=np.arange(10).astype(dt))
    out.append(Case("hdf5: a 65535 x 65535 sensor", ["replay", str(p), "--save", str(folder / "c.rrd")]))
    return out


def build_cases(folder, seeds, sample: Path | None = None) -> list[Case]:
    """Write every hostile case into ``folder`` (``seeds``: valid recordings of every format, from
    :func:`fuzz_corpus.build_seeds`); returns them."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []
    cases += _hdf5_cases(folder)
    by = {}
    for s in seeds:
        by.setdefault(s.format, s)
    # a long run of zero bytes after valid data (sparse: 2 GB cost nothing on disk)
    text = folder / "one_line_then_zeros.txt"
    _sparse(text, b"0.1 1 2 1\n", 2 << 30)
    cases.append(Case("text: one line then 2 GB of zero bytes", ["info", str(text)], ("clean", "error")))
    cases.append(Case("text: zeros (replay)", ["replay", str(text), "--save", str(folder / "t.rrd")]))
    for fmt, name in (("necviz", "z.necrec"), ("aedat3", "z3.aedat"), ("aedat2", "z2.aedat")):
        if fmt in by:
            head = by[fmt].path.read_bytes()
            if fmt == "necviz":  # without its END chunk (9 bytes), as a crash leaves it: the zeros are read
                head = head[:-9]
            p = _sparse(folder / name, head, len(head) + (1 << 30))
            cases.append(Case(f"{fmt}: valid data then 1 GB of zero bytes", ["info", str(p)], ("clean", "error")))
            cases.append(Case(f"{fmt}: then zeros (replay)", ["replay", str(p), "--save", str(folder / f"{name}.rrd")]))
    if sample is not None and Path(sample).is_file():
        data = Path(sample).read_bytes()
        p = _sparse(folder / "z4.aedat4", data, len(data) + (1 << 30))
        cases.append(Case("aedat4: sample then 1 GB of zero bytes", ["info", str(p)], ("clean", "error")))
        for label, (at, value) in (("panic", PANIC_BYTE), ("warning", WARN_BYTE)):
            b = bytearray(data)
            b[at] = value
            p = folder / f"{label}.aedat4"
            p.write_bytes(bytes(b))
            expect = ("error",) if label == "panic" else ("clean",)
            cases.append(
                Case(
                    f"aedat4: a byte that makes the decoder {label} (replay)",
                    ["replay", str(p), "--save", str(folder / f"{label}.rrd")],
                    expect,
                )
            )
            cases.append(Case(f"aedat4: a byte that makes the decoder {label} (info)", ["info", str(p)], ("clean",)))
    # not regular files under recording names
    for name in ("pipe.aedat4", "pipe.necrec", "pipe.txt"):
        p = folder / name
        os.mkfifo(p)
        cases.append(Case(f"a named pipe called {name}", ["info", str(p)]))
        cases.append(Case(f"a named pipe called {name} (replay)", ["replay", str(p), "--save", str(folder / "p.rrd")]))
    os.symlink("/dev/zero", folder / "zero.aedat4")
    cases.append(Case("/dev/zero behind a link called zero.aedat4", ["info", str(folder / "zero.aedat4")]))
    os.symlink("loop_b.aedat4", folder / "loop_a.aedat4")
    os.symlink("loop_a.aedat4", folder / "loop_b.aedat4")
    cases.append(Case("a symbolic link loop", ["replay", str(folder / "loop_a.aedat4")]))
    (folder / "folder.aedat4").mkdir()
    cases.append(Case("a folder called folder.aedat4", ["info", str(folder / "folder.aedat4")]))
    (folder / "empty.aedat4").write_bytes(b"")
    cases.append(Case("an empty file", ["info", str(folder / "empty.aedat4")]))
    # valid recordings under names that are not UTF-8
    raw = os.fsencode(folder) + b"/\xff\xfe"
    for s in seeds:
        dst = raw + os.fsencode(s.path.name)
        if s.path.is_dir():
            shutil.copytree(os.fsencode(s.path), dst)
        else:
            shutil.copyfile(os.fsencode(s.path), dst)
        cases.append(
            Case(f"{s.format}: a valid file named with non-UTF-8 bytes", ["info", os.fsdecode(dst)], ("clean",))
        )
    cases += path_cases(folder / "paths", by.get("necviz").path if "necviz" in by else None)
    return cases


def path_cases(folder, recording) -> list[Case]:
    """Outputs that name an input (directly, through a link), a folder, a device, a file in a folder's place;
    every input must come out byte-identical, and no output may appear."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rec = folder / "in.necrec"
    shutil.copyfile(recording, rec)
    prof = folder / "prof.json"
    shutil.copyfile(Path(__file__).resolve().parents[1] / "necviz" / "profiles" / "davis346-sim.json", prof)
    scen = folder / "s.toml"
    scen.write_text('name = "tunnel_exit"\nduration_s = 0.1\n')
    os.symlink("prof.json", folder / "prof_link.json")
    os.link(prof, folder / "prof_hard.json")
    os.symlink("in.necrec", folder / "rec_link.necrec")
    os.link(rec, folder / "rec_hard.necrec")
    keep = [rec, prof, scen]
    save = str(folder / "out.rrd")
    out = []
    for how, target in (("the same name", prof), ("a symbolic link", folder / "prof_link.json")):
        for extra in ([], ["--force"]):
            out.append(
                Case(
                    f"replay --json is the --profile ({how}){' --force' if extra else ''}",
                    ["replay", str(rec), "--profile", str(prof), "--json", str(target), "--save", save, *extra],
                    keep=keep,
                    absent=[save],
                    group="paths",
                )
            )
    out.append(
        Case(
            "replay --json is the --profile (a hard link) --force",
            ["replay", str(rec), "--profile", str(prof), "--json", str(folder / "prof_hard.json"), "--force"],
            keep=keep,
            group="paths",
        )
    )
    for target in (rec, folder / "rec_link.necrec", folder / "rec_hard.necrec"):
        out.append(
            Case(
                f"info --json is the recording ({target.name}) --force",
                ["info", str(rec), "--json", str(target), "--force"],
                keep=keep,
                group="paths",
            )
        )
    out.append(
        Case(
            "demo --record and --save name one file (a link) --force",
            [
                "demo",
                "--duration",
                "0.1",
                "--record",
                str(folder / "r.necrec"),
                "--save",
                str(_link(folder / "r.necrec", folder / "r_link.rrd")),
                "--force",
                "--no-prompt",
            ],
            absent=[folder / "r.necrec"],
            group="paths",
        )
    )
    out.append(
        Case(
            "compare --json is the --profile --force",
            ["compare", "--duration", "0.1", "--no-sift", "--profile", str(prof), "--json", str(prof), "--force"],
            keep=keep,
            group="paths",
        )
    )
    out.append(
        Case(
            "compare --json is the --scenario --force",
            ["compare", "--scenario", str(scen), "--no-sift", "--json", str(scen), "--force"],
            keep=keep,
            group="paths",
        )
    )
    out.append(
        Case(
            "compare --save is the --scenario (renamed .rrd through a link) --force",
            ["compare", "--scenario", str(scen), "--no-sift", "--save", str(_link(scen, folder / "s.rrd")), "--force"],
            keep=keep,
            group="paths",
        )
    )
    out.append(
        Case(
            "calibrate --out is the --profile --force",
            ["calibrate", "--sim", "calibration", "--profile", str(prof), "--out", str(prof), "--force"],
            keep=keep,
            group="paths",
        )
    )
    for label, target in (
        ("a folder", folder),
        ("/dev/null", Path("/dev/null")),
        ("a file in a folder's place", _plain_file(folder / "plain.txt") / "x.json"),  # (a missing one is made)
        ("a dangling link", _link(folder / "nowhere.json", folder / "dangling.json")),
    ):
        out.append(
            Case(
                f"info --json is {label} --force",
                ["info", str(rec), "--json", str(target), "--force"],
                keep=keep,
                group="paths",
            )
        )
    return out


def _plain_file(path: Path) -> Path:
    if not path.exists():
        path.write_text("a file, not a folder\n")
    return path


def _link(target: Path, link: Path) -> Path:
    if not link.is_symlink():
        os.symlink(target.name if target.parent == link.parent else target, link)
    return link


def _digest(path: Path) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _status(key: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    return 0


def run_case(case: Case, time_limit: float = 10.0) -> dict:
    """Run ``case`` through :func:`necviz.commands.cli.main` here, with fd 2 captured, a SIGALRM after
    ``4 x time_limit`` (a Python-level hang) and the checks of the module docstring. Returns
    ``{"name", "outcome", "code", "seconds", "memory_mb", "stderr", "changed", "appeared"}``."""
    from necviz.commands.cli import main

    before = {str(p): _digest(p) for p in case.keep}
    err = tempfile.TemporaryFile()
    saved = os.dup(2)
    measured = _reset_peak()
    base = _status("VmRSS:") if measured else 0

    def hang(signum, frame):
        raise TimeoutError(f"still running after {4 * time_limit:g} s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.setitimer(signal.ITIMER_REAL, 4 * time_limit)
    t0 = time.perf_counter()
    os.dup2(err.fileno(), 2)
    try:
        code = main(list(case.argv))
    except TimeoutError:
        code = "hang"
    except BaseException as exc:  # noqa: BLE001 - what the harness counts
        if isinstance(exc, KeyboardInterrupt):
            raise
        code = f"exception {type(exc).__name__}: {exc}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        os.dup2(saved, 2)
        os.close(saved)
    seconds = time.perf_counter() - t0
    memory = max(0, _status("VmHWM:") - base) if measured else 0
    err.seek(0)
    text = err.read().decode("utf-8", "replace")
    err.close()
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if code == 0:
        outcome = "clean" if not lines else "traceback"
    elif code == 2 and len(lines) == 1 and lines[0].startswith("necviz: error: "):
        outcome = "error"
    elif code == "hang":
        outcome = "hang"
    else:
        outcome = "traceback"
    changed = [p for p, d in before.items() if _digest(p) != d]
    appeared = [str(p) for p in case.absent if os.path.lexists(p)]
    return {
        "name": case.name,
        "group": case.group,
        "outcome": outcome,
        "expected": list(case.expect),
        "code": code if isinstance(code, int) else str(code)[:200],
        "seconds": seconds,
        "memory_mb": memory / 2**20,
        "stderr": text[-600:],
        "changed": changed,
        "appeared": appeared,
    }


def problems(r: dict, time_limit: float = 10.0, memory_mb: float = 512.0) -> list[str]:
    """What is wrong with a :func:`run_case` result (empty: the case passed)."""
    bad = []
    if r["outcome"] not in r["expected"]:
        bad.append(f"{r['outcome']} (expected {'/'.join(r['expected'])}): {r['stderr'].strip()[-300:]!r}")
    if r["seconds"] > time_limit:
        bad.append(f"took {r['seconds']:.1f} s")
    if r["memory_mb"] > memory_mb:
        bad.append(f"grew by {r['memory_mb']:.0f} MB")
    if r["changed"]:
        bad.append(f"changed {r['changed']}")
    if r["appeared"]:
        bad.append(f"left {r['appeared']}")
    return bad


__all__ = ["Case", "PANIC_BYTE", "WARN_BYTE", "build_cases", "path_cases", "problems", "replay_variants", "run_case"]


def replay_variants(seeds, n: int, seed: int, folder) -> list[Case]:
    """``n`` corrupted copies (:class:`fuzz_corpus.VariantMaker`) of the AEDAT 3.1, AEDAT 2.0 and HDF5
    seeds, each through ``necviz replay`` (the issue found 16 of 765 such replays past 4 GB)."""
    from fuzz_corpus import VariantMaker

    chosen = [s for s in seeds if s.format in ("aedat3", "aedat2", "hdf5")]
    maker = VariantMaker(chosen, seed, Path(folder))
    out = []
    for i in range(n):
        fmt, kind, path = maker.make(i)
        rrd = Path(folder) / f"r{i:05d}.rrd"
        out.append(
            Case(
                f"replay {fmt} {kind} #{i}",
                ["replay", str(path), "--save", str(rrd)],
                ("clean", "error"),
                group="replay",
            )
        )
    return out


def main(argv=None) -> int:
    """``python tests/hostile.py OUT.json FOLDER [REPLAY_VARIANTS]``: build the cases (and that many
    corrupted replays), run them all here, write the results. The fast test runs this in a
    subprocess, so a case that runs away cannot take the test runner with it."""
    import json

    argv = sys.argv[1:] if argv is None else argv
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fuzz_corpus import SAMPLE_AEDAT4, build_seeds

    folder = Path(argv[1]) if len(argv) > 1 else Path(tempfile.mkdtemp(prefix="necviz-hostile-"))
    seeds = build_seeds(folder / "seeds", seed=0)
    cases = build_cases(folder / "cases", seeds, SAMPLE_AEDAT4)
    if len(argv) > 2:
        cases += replay_variants(seeds, int(argv[2]), 23, folder / "replays")
    os.chdir(folder)
    results = [run_case(c) for c in cases]
    Path(argv[0]).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
