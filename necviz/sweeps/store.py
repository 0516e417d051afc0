"""The sweep folder ``OUT/``: what is written where, atomically, and how it is read back.

Layout::

    OUT/manifest.json            the sweep file (text and parsed), the expanded grid (hash and spec of
                                 every run), versions, the git revision, the machine, every session
    OUT/sweep.toml               a copy of the sweep file
    OUT/runs/<hash>.parquet      one row per finished run (ok or failed)
    OUT/runs/<hash>.trace.parquet  that run's per-frame records (ok runs)
    OUT/report/                  what ``necviz sweep report`` writes
    OUT/.lock                    held while a ``sweep run`` writes here

A run is done when its row exists: the trace is written first, then the row, each to a temporary
file in ``runs/`` renamed into place (:func:`necviz.outputs.atomic_write`), so a crash or Ctrl-C
leaves either a complete row or none, never half of one. A row damaged afterwards (a truncated
copy, a file emptied by a full disk) is not a finished run: :meth:`Store.check_rows` finds it by
the Parquet framing (``PAR1`` at both ends, a footer that fits), ``status`` and ``report`` name it
in one line and leave it out, and ``sweep run --resume`` runs it again.
"""

from __future__ import annotations

import json
import os
import platform
import socket
import subprocess
import sys
import time
from pathlib import Path

from necviz.core.errors import ParameterError
from necviz.outputs import atomic_write, write_json

#: the files ``necviz sweep report`` writes into a sweep folder (replaced, never mixed with the runs)
REPORT_FILES = ("report.md", "cells.csv", "runs.csv")

MANIFEST = "manifest.json"
FORMAT = "necviz-sweep/1"
ROW_SUFFIX = ".parquet"
TRACE_SUFFIX = ".trace.parquet"


class SweepDirError(ParameterError):
    """``OUT`` is not a sweep folder, or cannot be written as asked."""


class Store:
    """A sweep folder (see the module docstring)."""

    def __init__(self, root):
        self.root = Path(root)
        self.runs = self.root / "runs"
        self.unreadable: dict[str, str] = {}  # hash -> why, of the rows the last read_rows left out

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    def is_sweep(self) -> bool:
        return self.manifest_path.is_file()

    def manifest(self) -> dict:
        try:
            m = json.loads(self.manifest_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise SweepDirError(
                f"{self.root} is not a sweep folder (no {MANIFEST}; run `necviz sweep run` first)"
            ) from None
        except (OSError, ValueError) as e:
            raise SweepDirError(f"cannot read {self.manifest_path}: {e}") from None
        if not isinstance(m, dict) or m.get("format") != FORMAT:
            raise SweepDirError(f"{self.manifest_path} is not a necviz sweep manifest")
        return m

    def write_manifest(self, manifest: dict) -> None:
        write_json(self.manifest_path, manifest, indent=1)

    # rows ---------------------------------------------------------------------------------------
    def row_path(self, h: str) -> Path:
        return self.runs / f"{h}{ROW_SUFFIX}"

    def trace_path(self, h: str) -> Path:
        return self.runs / f"{h}{TRACE_SUFFIX}"

    def done(self) -> set[str]:
        """Hashes with a row (finished or failed)."""
        if not self.runs.is_dir():
            return set()
        return {
            p.name[: -len(ROW_SUFFIX)]
            for p in self.runs.iterdir()
            if p.name.endswith(ROW_SUFFIX) and not p.name.endswith(TRACE_SUFFIX) and not p.name.startswith(".")
        }

    def write_run(self, h: str, row: bytes, trace: bytes | None) -> None:
        """Trace first, then the row (the row marks the run done); each atomically."""
        if trace is not None:
            _write_bytes(self.trace_path(h), trace)
        _write_bytes(self.row_path(h), row)

    def read_row(self, h: str, columns: list[str] | None = None) -> dict:
        """One row as a dict, with its metric names under ``"__metrics__"`` (``columns``: only those).

        Raises :class:`SweepDirError` (one line) if the row file is damaged."""
        import pyarrow.parquet as pq

        path = self.row_path(h)
        try:
            f = pq.ParquetFile(path)
            if columns is not None:
                columns = [c for c in columns if c in f.schema_arrow.names]
            t = f.read(columns=columns)
            row = t.to_pylist()[0]
            meta = f.schema_arrow.metadata or {}
            row["__metrics__"] = json.loads(meta.get(b"necviz.metrics", b"[]"))
        except (OSError, ValueError, IndexError, KeyError, TypeError) as e:
            why = " ".join(str(e).split())[:120] or type(e).__name__
            raise SweepDirError(
                f"{path}: unreadable result row ({why}); `necviz sweep run FILE --out {self.root} --resume` runs it again"
            ) from None
        return row

    def check_rows(self, hashes) -> dict[str, str]:
        """The rows among ``hashes`` whose file is damaged: ``{hash: why}`` (empty, truncated, not
        Parquet). A cheap check of the framing (two small reads per row), not of every value."""
        bad = {}
        for h in hashes:
            path = self.row_path(h)
            try:
                size = path.stat().st_size
                with open(path, "rb") as f:
                    head = f.read(4)
                    f.seek(max(0, size - 8))
                    tail = f.read(8)
            except OSError as e:
                bad[h] = e.strerror or str(e)
                continue
            if size == 0:
                bad[h] = "empty file"
            elif size < 12 or head != b"PAR1" or tail[4:] != b"PAR1":
                bad[h] = "truncated or not a Parquet file"
            elif int.from_bytes(tail[:4], "little") > size - 12:
                bad[h] = "truncated (its footer does not fit)"
        return bad

    def read_rows(self, hashes=None, columns: list[str] | None = None, skip_bad: bool = False) -> list[dict]:
        """Every row (or those of ``hashes``, in that order), as dicts with ``"__metrics__"``.

        ``skip_bad``: leave out damaged rows and list them in ``self.unreadable`` (``{hash: why}``)
        instead of raising."""
        hashes = sorted(self.done()) if hashes is None else [h for h in hashes if self.row_path(h).is_file()]
        self.unreadable = {}
        if not skip_bad:
            return [self.read_row(h, columns) for h in hashes]
        bad = self.check_rows(hashes)
        rows = []
        for h in hashes:
            if h in bad:
                continue
            try:
                rows.append(self.read_row(h, columns))
            except SweepDirError as e:
                bad[h] = str(e).split("unreadable result row (", 1)[-1].split(");", 1)[0]
        self.unreadable = bad
        return rows

    def unreadable_note(self, sweep_file: str | None = None) -> str | None:
        """One line about the rows :meth:`read_rows` left out, or None."""
        bad = self.unreadable
        if not bad:
            return None
        h, why = next(iter(bad.items()))
        more = f" and {len(bad) - 1} more" if len(bad) > 1 else ""
        how = f"necviz sweep run {sweep_file or 'FILE'} --out {self.root} --resume"
        return (
            f"{len(bad)} result row{'s' if len(bad) > 1 else ''} unreadable ({self.row_path(h).name}: {why}{more}); "
            f"left out here, `{how}` runs {'them' if len(bad) > 1 else 'it'} again"
        )

    def find(self, prefix: str) -> str:
        """The hash starting with ``prefix`` (at least 4 characters); one-line errors otherwise."""
        prefix = str(prefix).strip().lower()
        if len(prefix) < 4 or any(c not in "0123456789abcdef" for c in prefix):
            raise SweepDirError(f"--run expects a run hash (at least 4 hex digits), got {prefix!r}")
        hits = sorted(h for h in self.done() if h.startswith(prefix))
        if not hits:
            raise SweepDirError(f"no run {prefix!r} in {self.runs} (see `necviz sweep status {self.root}`)")
        if len(hits) > 1:
            raise SweepDirError(f"--run {prefix!r} matches {len(hits)} runs ({', '.join(hits[:4])}…); give more digits")
        return hits[0]

    # the lock -----------------------------------------------------------------------------------
    def lock(self) -> None:
        """Take ``OUT/.lock`` (another live ``sweep run`` here is refused; a stale lock is taken over)."""
        path = self.root / ".lock"
        me = f"{socket.gethostname()} {os.getpid()}"
        for _ in range(2):
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                try:
                    host, pid = path.read_text().split()
                except (OSError, ValueError):
                    host, pid = "", "0"
                if host == socket.gethostname() and not _alive(int(pid)):
                    path.unlink(missing_ok=True)
                    continue
                raise SweepDirError(
                    f"another sweep is writing to {self.root} (process {pid} on {host or '?'}); "
                    f"if it is gone, delete {path}"
                ) from None
            with os.fdopen(fd, "w") as f:
                f.write(me)
            return
        raise SweepDirError(f"cannot take the lock {path}")

    def unlock(self) -> None:
        (self.root / ".lock").unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_MODE: int | None = None


def _file_mode() -> int:
    """0o666 less the umask (what ``open`` would give; the temporary files are created 0o600)."""
    global _MODE
    if _MODE is None:
        mask = os.umask(0o022)
        os.umask(mask)
        _MODE = 0o666 & ~mask
    return _MODE


def _write_bytes(path: Path, data: bytes) -> None:
    with atomic_write(path, "wb") as f:
        f.write(data)
        os.fchmod(f.fileno(), _file_mode())


def prepare_out(out, *, resume: bool, force: bool) -> Store:
    """Check ``OUT`` before anything starts: new or empty, a sweep folder with ``--resume``, or (with
    ``--force``) a sweep folder whose rows, manifest and report are deleted."""
    root = Path(out)
    store = Store(root)
    if str(out) == "":
        raise SweepDirError("--out needs a folder name")
    if root.exists() and not root.is_dir():
        raise SweepDirError(f"--out: {root} is a file, not a folder")
    if not root.exists() and not root.parent.is_dir():
        from necviz.outputs import make_folder

        make_folder(root.parent, "--out")
    empty = not root.exists() or not any(root.iterdir())
    if resume:
        if empty or not store.is_sweep():
            raise SweepDirError(f"--resume: {root} holds no sweep to resume (no {MANIFEST})")
        store.manifest()
    elif not empty:
        if not force:
            raise SweepDirError(
                f"--out: {root} is not empty; pass --resume to complete that sweep or --force to start it over"
            )
        if not store.is_sweep():
            raise SweepDirError(f"--force: {root} is not a sweep folder (no {MANIFEST}); choose a new or empty folder")
        _clear(store)
    root.mkdir(exist_ok=True)
    store.runs.mkdir(exist_ok=True)
    if not os.access(root, os.W_OK) or not os.access(store.runs, os.W_OK):
        raise SweepDirError(f"--out: {root} is not writable")
    return store


def _clear(store: Store) -> None:
    """Delete what a sweep wrote (rows, traces, manifest, copy of the sweep file, report); nothing else."""
    if store.runs.is_dir():
        for p in store.runs.iterdir():
            if p.is_file() and p.name.endswith(ROW_SUFFIX):
                p.unlink()
    for name in (MANIFEST, "sweep.toml"):
        (store.root / name).unlink(missing_ok=True)
    rep = store.root / "report"
    if rep.is_dir():
        for p in rep.iterdir():
            if p.is_file() and (p.name in REPORT_FILES or (p.name.startswith("plot-") and p.suffix == ".png")):
                p.unlink()


# -- what the manifest records about where and how it ran ----------------------------------------------
def versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in (
        "necviz",
        "numpy",
        "numba",
        "scipy",
        "opencv-python-headless",
        "pyarrow",
        "dask",
        "distributed",
        "matplotlib",
        "rerun-sdk",
    ):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def git_revision() -> dict | None:
    """The revision of the source tree necviz runs from (``None`` outside a git checkout)."""
    here = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=20,
        )
        return {"revision": rev.stdout.strip(), "dirty": bool(dirty.stdout.strip()) if dirty.returncode == 0 else None}
    except (OSError, subprocess.SubprocessError):
        return None


def machine() -> dict:
    mem = None
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        pass
    return {
        "hostname": socket.gethostname(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor() or None,
        "cpu_count": os.cpu_count(),
        "memory_bytes": mem,
        "executable": sys.executable,
    }


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


__all__ = ["MANIFEST", "Store", "SweepDirError", "git_revision", "machine", "now", "prepare_out", "versions"]
