"""Output files that never destroy inputs or earlier work.

Every file a command writes (``--json``, ``--save``, ``--record``, calibration profiles, sweep
results, reports) goes through this module:

* :func:`check_output` runs before anything starts (no camera opened, no simulation run): the
  path is not a folder, its folder exists and is writable, it is not the same file as any input
  (compared by resolved path and by inode, so a hard link or ``./x`` vs ``x`` is caught), it has
  the expected extension, and it does not exist unless the user asked to replace it (``--force``).
* :func:`atomic_write` writes to a temporary file in the same folder and renames it into place
  only when writing succeeded: a failure leaves any earlier file untouched and no half-written one.
* Recordings stream for minutes and must stay readable after a crash, so they are written under
  their final name; :func:`recording_target` says where: the path itself when it did not exist
  (created exclusively, so a file appearing meanwhile is not clobbered), or a temporary sibling
  renamed over the old file on success (:func:`commit_recording`) when the user passed ``--force``.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable
from contextlib import contextmanager
from pathlib import Path

from necviz.core.errors import ParameterError


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.resolve() == b.resolve():
            return True
        sa, sb = a.stat(), b.stat()
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def check_output(
    path, flag: str, *, inputs: Iterable = (), force: bool = False, suffixes: tuple[str, ...] | None = None
) -> Path:
    """Refuse an output path that would destroy an input or an existing file; return it as a Path.

    ``flag`` names the option in the one-line error (``--json``); ``inputs`` are the files the
    command reads; ``suffixes`` the accepted extensions (``(".rrd",)``); ``force`` allows
    replacing an existing file (never an input).
    """
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise ParameterError(f"{flag}: {str(path)!r} is not a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise ParameterError(f"{flag} expects a {' or '.join(suffixes)} file name, got {str(p)!r}")
    if p.is_dir():
        raise ParameterError(f"{flag}: {str(p)!r} is a folder, not a file")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ParameterError(f"{flag}: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise ParameterError(f"{flag}: folder {str(parent)!r} is not writable")
    for inp in inputs:
        if inp is not None and _same_file(p, Path(inp)):
            raise ParameterError(f"{flag}: {str(p)!r} is the input file {str(inp)!r}; choose another name")
    if p.exists() and not force:
        raise ParameterError(f"{flag}: {str(p)!r} already exists; pass --force to replace it")
    return p


def check_distinct(outputs: dict) -> None:
    """Two outputs of one command must not be the same file (``--record X --save X``)."""
    seen: dict[str, str] = {}
    for flag, path in outputs.items():
        if path is None:
            continue
        key = str(Path(path).resolve())
        if key in seen:
            raise ParameterError(f"{flag} and {seen[key]} name the same file {str(path)!r}")
        seen[key] = flag


@contextmanager
def atomic_write(path, mode: str = "w", encoding: str | None = "utf-8"):
    """Open a temporary file beside ``path``; on success rename it over ``path``, on error delete it."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
    try:
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_json(path, data, indent: int | None = 2) -> None:
    """``data`` as JSON at ``path``, atomically."""
    with atomic_write(path) as f:
        json.dump(data, f, indent=indent)
        f.write("\n")


def recording_target(path) -> Path:
    """Where to stream a recording bound for ``path`` (see the module docstring).

    A new file is created exclusively here (an empty file marks the name as taken); an existing
    one (replaced with ``--force``) is left alone until :func:`commit_recording`.
    """
    p = Path(path)
    try:
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        parent = p.parent if str(p.parent) else Path(".")
        fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=f".partial{p.suffix}", dir=parent)
        os.close(fd)
        return Path(tmp)
    os.close(fd)
    return p


def commit_recording(target: Path, path) -> None:
    """Move a finished recording from its :func:`recording_target` to ``path`` (no-op when they agree)."""
    if Path(target) != Path(path):
        os.replace(target, path)


__all__ = ["atomic_write", "check_distinct", "check_output", "commit_recording", "recording_target", "write_json"]
