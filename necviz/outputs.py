"""Output files that never destroy inputs or earlier work, and never stay behind half-written.

Every file a command writes (``--json``, ``--save``, ``--record``, ``--out``, calibration profiles,
sweep results, reports) goes through this module. The rules (``docs/robustness.md``):

* **Checked before anything starts** (:func:`check_output`, no camera opened, no simulation run):
  the path is not a folder or a device, its folder exists (a missing one is created, parents too,
  and the command says so in one line: :func:`make_folder`) and is writable, it has the expected
  extension, it does not exist unless the user asked to replace it (``--force``), and it is none of
  the command's inputs (:func:`check_not_input`) — compared by resolved path and by device and
  inode, so ``./x`` vs ``x``, a symbolic link and a hard link are all caught, with or without
  ``--force``.
* **Written beside, renamed into place when complete** (:func:`atomic_output`): a temporary file
  in the same folder receives the data, is flushed to disk and renamed over the final name only
  when writing succeeded, with the permissions a new file gets (``0o666`` less the umask). On any
  failure (a full disk included) the temporary file is deleted and the error
  (:class:`OutputError`) says that nothing was written; an existing file is left as it was.
* **Recordings** stream for minutes (:class:`StreamedOutput`; ``--record``'s native file:
  :class:`RecordingFile`): a new file is written under its own
  name from the first byte on (a crash leaves it readable up to its last flush); replacing an
  existing file writes beside it and renames over it only when the run has ended. When the run
  fails, what was written is deleted — unless the recording holds data that cannot be produced
  again (a camera session: ``keep_partial``), which is then kept and named in the error.
* **Space**: a recording is not started with less than :data:`RECORDING_RESERVE` bytes free on
  its disk, and a session stops cleanly when the free space falls below half of that
  (:func:`check_space`), so files end whole instead of cut by a full disk.

For writers outside the command line (exports, notebooks)::

    check_not_input({"--out": out}, [recording, profile])   # one-line ParameterError otherwise
    with atomic_output(out, "wb") as f:                     # OutputError on failure, nothing left
        f.write(data)
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from collections.abc import Iterable, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Protocol

from necviz.core.errors import NecvizError, ParameterError

#: Free bytes a recording needs on its disk to start (and half of it to go on): Rerun and the
#: native recorder buffer a few MiB, so a run stops whole well before the disk is full. The
#: environment variable ``NECVIZ_DISK_RESERVE_MB`` changes it (0 turns the check off).
RECORDING_RESERVE = 64 << 20


def _reserve() -> int:
    text = os.environ.get("NECVIZ_DISK_RESERVE_MB")
    if text is None:
        return RECORDING_RESERVE
    try:
        v = float(text)
    except ValueError:
        raise ParameterError(f"NECVIZ_DISK_RESERVE_MB must be a number of MB, got {text!r}") from None
    if not (v >= 0 and v < 1e9):
        raise ParameterError(f"NECVIZ_DISK_RESERVE_MB must be a number of MB >= 0, got {text!r}")
    return int(v * (1 << 20))


class OutputError(NecvizError):
    """An output could not be written (a full disk, an I/O error); the message says what is left."""


# -- folders ---------------------------------------------------------------------------------------
def make_folder(folder, flag: str, announce=None) -> Path:
    """Create ``folder`` (and its parents) when it is missing, saying so in one line on ``announce``
    (default standard output); returns it.

    Raises
    ------
    ParameterError
        A file (or something else) is in the way, or the folder cannot be created.
    """
    import sys

    f = Path(folder)
    if f.is_dir():
        return f
    if os.path.lexists(f):
        raise ParameterError(f"{flag}: {str(f)!r} is a file, not a folder")
    try:
        f.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ParameterError(f"{flag}: cannot create folder {str(f)!r} ({e.strerror or e})") from None
    print(f"  created folder {str(f)!r} for {flag}", file=announce or sys.stdout, flush=True)
    return f


# -- identity --------------------------------------------------------------------------------------
def _key(p: Path) -> tuple[str, tuple[int, int] | None]:
    """(resolved path, (device, inode) or None) of ``p``; a loop or an unreadable link gives its text."""
    try:
        resolved = os.path.realpath(p)
    except (OSError, ValueError):
        resolved = os.path.abspath(p)
    try:
        st = os.stat(p)
        ident = (st.st_dev, st.st_ino)
    except (OSError, ValueError):
        ident = None
    return resolved, ident


def same_file(a, b) -> bool:
    """Whether ``a`` and ``b`` name the same file: same resolved path (links followed) or same device
    and inode (a hard link)."""
    ka, kb = _key(Path(a)), _key(Path(b))
    return ka[0] == kb[0] or (ka[1] is not None and ka[1] == kb[1])


def _inside(path, folder) -> bool:
    try:
        Path(os.path.realpath(path)).relative_to(os.path.realpath(folder))
        return True
    except (ValueError, OSError):
        return False


def _named(items, default: str) -> list[tuple[str, object]]:
    if items is None:
        return []
    if isinstance(items, Mapping):
        return [(str(k), v) for k, v in items.items() if v is not None]
    if isinstance(items, (str, os.PathLike)):
        return [(default, items)]
    return [(default, v) for v in items if v is not None]


def check_not_input(outputs, inputs) -> None:
    """Refuse any output that is one of the inputs (or an existing file inside an input folder).

    Parameters
    ----------
    outputs : mapping or iterable
        ``{flag: path}`` (``{"--json": "out.json"}``; ``None`` paths are skipped) or paths.
    inputs : mapping or iterable
        The files (or recording folders) the command reads: ``{name: path}`` or paths.

    Raises
    ------
    ParameterError
        One line naming the output's flag and the input it would destroy. ``--force`` never
        lifts this: an output may not replace an input by path, symbolic link or hard link, nor
        an existing file inside an input folder (a ROS 2 bag, an RPG text folder); a new file may
        be written there.
    """
    ins = _named(inputs, "input")
    for flag, out in _named(outputs, "output"):
        for name, inp in ins:
            label = "the input file" if name == "input" else f"the {name} file"
            if same_file(out, inp):
                link = "" if os.path.abspath(out) == os.path.abspath(inp) else " (the same file through a link)"
                raise ParameterError(f"{flag}: {str(out)!r} is {label} {str(inp)!r}{link}; choose another name")
            if os.path.isdir(inp) and os.path.lexists(out) and _inside(out, inp):
                raise ParameterError(
                    f"{flag}: {str(out)!r} is a file of the input folder {str(inp)!r}; choose another name"
                )


def check_output(
    path, flag: str, *, inputs: Iterable = (), force: bool = False, suffixes: tuple[str, ...] | None = None
) -> Path:
    """Refuse an output path that would destroy an input or an existing file; return it as a Path.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    flag : str
        The option named in the one-line error (``"--json"``).
    inputs : iterable or mapping
        The files the command reads (see :func:`check_not_input`).
    force : bool
        Allow replacing an existing regular file (never an input, never a folder or device).
    suffixes : tuple of str, optional
        Accepted extensions (``(".rrd",)``).

    Returns
    -------
    Path
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    ParameterError
        One line saying what is wrong.
    """
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise ParameterError(f"{flag}: {str(path)!r} is not a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise ParameterError(f"{flag} expects a {' or '.join(suffixes)} file name, got {str(p)!r}")
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as e:  # a symbolic link loop, a name too long, a path through a file
        raise ParameterError(f"{flag}: {str(p)!r} cannot be used ({e.strerror or e})") from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise ParameterError(f"{flag}: {str(p)!r} is a folder, not a file")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise ParameterError(f"{flag}: {str(p)!r} exists and is not a regular file ({_kind(st.st_mode)})")
    if st is None and os.path.islink(p):
        raise ParameterError(f"{flag}: {str(p)!r} is a symbolic link to nothing; remove it or choose another name")
    parent = Path(os.path.realpath(p)).parent
    if not parent.is_dir():
        make_folder(p.parent, flag)
    if not os.access(parent, os.W_OK):
        raise ParameterError(f"{flag}: folder {str(parent)!r} is not writable")
    check_not_input({flag: p}, inputs)
    if st is not None and not force:
        raise ParameterError(f"{flag}: {str(p)!r} already exists; pass --force to replace it")
    return p


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISFIFO, "a named pipe"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_distinct(outputs: dict) -> None:
    """Two outputs of one command must not be the same file (``--record X --save X``), by path or link."""
    seen: list[tuple[str, object]] = []
    for flag, path in outputs.items():
        if path is None:
            continue
        for other_flag, other in seen:
            if same_file(path, other):
                raise ParameterError(f"{flag} and {other_flag} name the same file {str(path)!r}")
        seen.append((flag, path))


# -- space -----------------------------------------------------------------------------------------
def free_bytes(path) -> int | None:
    """Bytes an unprivileged writer may still use on the disk holding ``path`` (its folder if it does
    not exist yet); ``None`` if unknown."""
    folder = Path(os.path.realpath(path))
    if not folder.is_dir():
        folder = folder.parent
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


def check_space(path, flag: str, need: int | None = None) -> None:
    """Refuse to start writing ``path`` (a recording) with less than ``need`` bytes free on its disk
    (default: :data:`RECORDING_RESERVE`)."""
    need = _reserve() if need is None else need
    free = free_bytes(path)
    if free is not None and free < need:
        raise OutputError(
            f"{flag}: only {_size(free)} free on the disk holding {str(path)!r}; a recording needs at least "
            f"{_size(need)}; nothing was written"
        )


def low_space(paths, need: int | None = None, extra: int = 0) -> tuple[str, int] | None:
    """The first of ``paths`` whose disk has fewer than ``need`` bytes free (default: half of
    :data:`RECORDING_RESERVE`) plus ``extra`` (what completing the files will still write, e.g. a
    segmented ``--save`` joined into one file): ``(path, free)``, else None."""
    need = (_reserve() // 2 if need is None else need) + int(extra)
    for p in paths:
        if p is None:
            continue
        free = free_bytes(p)
        if free is not None and free < need:
            return str(p), free
    return None


def _size(n: int) -> str:
    for unit, k in (("GB", 1 << 30), ("MB", 1 << 20), ("kB", 1 << 10)):
        if n >= k:
            return f"{n / k:.1f} {unit}"
    return f"{n} bytes"


# -- permissions -----------------------------------------------------------------------------------
def new_file_mode() -> int:
    """The permissions ``open(path, "w")`` gives a new file: ``0o666`` less the process umask."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)  # no /proc: read it by setting it (and putting it back at once)
    os.umask(mask)
    return 0o666 & ~mask


# -- writing ---------------------------------------------------------------------------------------
def write_failed(path, exc: BaseException, existed: bool, flag: str | None = None) -> OutputError:
    """The one-line :class:`OutputError` for a write of ``path`` that failed with ``exc`` and left nothing."""
    what = getattr(exc, "strerror", None) or " ".join(str(exc).split()) or type(exc).__name__
    kept = f" (the existing {Path(path).name} is unchanged)" if existed else ""
    pre = f"{flag}: " if flag else ""
    return OutputError(f"{pre}cannot write {str(path)!r}: {what}; nothing was written{kept}")


def _destination(path) -> Path:
    """Where ``path``'s data go: a symbolic link's target (the link itself stays a link)."""
    p = Path(path)
    return Path(os.path.realpath(p)) if os.path.islink(p) else p


@contextmanager
def atomic_output(path, mode: str = "wb", *, encoding: str | None = None, flag: str | None = None):
    """Write ``path`` through a temporary file beside it, renamed into place only when complete.

    Parameters
    ----------
    path : str or os.PathLike
        The final file (checked beforehand with :func:`check_output`).
    mode : str
        ``"wb"`` (bytes) or ``"w"`` (text, ``encoding`` default UTF-8).
    encoding : str, optional
        Text encoding for ``"w"``.
    flag : str, optional
        The option named in an error (``"--json"``).

    Yields
    ------
    file object
        The open temporary file.

    Raises
    ------
    OutputError
        The data could not be written (``OSError``: a full disk, an I/O error): the temporary file
        is deleted and the message says nothing was written (an existing file is unchanged).
        Any other exception raised inside the block propagates after the same clean-up.
    """
    dest = _destination(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    existed = dest.exists()
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=parent)
    except OSError as e:
        raise write_failed(path, e, existed, flag) from None
    try:
        with os.fdopen(fd, mode, encoding=None if "b" in mode else (encoding or "utf-8")) as f:
            yield f
            f.flush()
            os.fchmod(f.fileno(), new_file_mode())
            os.fsync(f.fileno())
        os.replace(tmp, dest)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError):  # a full disk (ENOSPC, EDQUOT, EFBIG), an I/O error, a vanished folder
            raise write_failed(path, e, existed, flag) from None
        raise


def atomic_write(path, mode: str = "w", encoding: str | None = "utf-8"):
    """:func:`atomic_output` with text mode by default (kept for the callers written before it)."""
    return atomic_output(path, mode, encoding=encoding)


def write_json(path, data, indent: int | None = 2, flag: str | None = None) -> None:
    """``data`` as JSON at ``path``, atomically (:func:`atomic_output`)."""
    text = json.dumps(data, indent=indent) + "\n"  # serialised first: a bad value writes nothing
    with atomic_output(path, "w", encoding="utf-8", flag=flag) as f:
        f.write(text)


class Output(Protocol):
    """A file a run writes and commits only when the run succeeded: the native recorder
    (:class:`RecordingFile`), the viewer's ``--save`` file. ``path`` is
    where it ends up; ``discard`` deletes it (or keeps it, readable, when asked) and returns a note."""

    path: Path

    def commit(self) -> None: ...

    def discard(self) -> str: ...


class StreamedOutput:
    """A recording streamed to ``path`` for the length of a run (see the module docstring).

    ``target`` is where the writer writes: ``path`` itself when it did not exist (claimed at once,
    exclusively, so a file appearing meanwhile is not clobbered), else a temporary sibling
    (``.NAME.XXXX.partial.EXT``) renamed over the old file by :meth:`commit`. :meth:`discard` ends
    a failed run: it deletes what was written (``keep_partial=False``) or keeps a non-empty
    recording under its final name, and returns the words for the error message.
    """

    def __init__(self, path, *, keep_partial: bool = False, flag: str | None = None):
        self.path = Path(path)
        self.flag = flag
        self.keep_partial = bool(keep_partial)
        self.done = False
        dest = _destination(self.path)
        self.dest = dest
        try:
            fd = os.open(dest, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            parent = dest.parent if str(dest.parent) else Path(".")
            try:
                fd, tmp = tempfile.mkstemp(prefix=f".{dest.stem}.", suffix=f".partial{dest.suffix}", dir=parent)
            except OSError as e:
                raise write_failed(self.path, e, True, flag) from None
            os.fchmod(fd, new_file_mode())
            os.close(fd)
            self.target = Path(tmp)
            self.replacing = True
            return
        except OSError as e:
            raise write_failed(self.path, e, False, flag) from None
        os.close(fd)
        self.target = dest
        self.replacing = False

    def commit(self) -> None:
        """The run succeeded: move the recording into place (no-op for a new file)."""
        if self.done:
            return
        self.done = True
        if self.target != self.dest:
            os.replace(self.target, self.dest)

    def discard(self) -> str:
        """The run failed: delete what was written, or keep it (``keep_partial`` and not empty).

        Returns what happened, for the error message: ``"nothing was written to X"``, ``"X is
        unchanged"`` or ``"the recording so far is in X"``."""
        if self.done:
            return ""
        self.done = True
        try:
            size = os.path.getsize(self.target)
        except OSError:
            size = 0
        if self.keep_partial and size > 0:
            if self.target != self.dest:
                os.replace(self.target, self.dest)
            return f"{_KEPT}{self.path}"
        try:
            os.unlink(self.target)
        except OSError:
            pass
        return f"{self.path} is unchanged" if self.replacing else f"{_LOST}{self.path}"


class RecordingFile:
    """The native recorder behind ``--record``: a :class:`~necviz.drivers.recordings.native.Recorder`
    streaming to ``path`` (checked beforehand with :func:`check_output`) through a :class:`StreamedOutput`,
    so a new file is readable up to its last flush after a crash and an existing one (``--force``) is
    replaced only when the run has succeeded. :meth:`close` completes the file, the run then
    :meth:`commit` s or :meth:`discard` s it (deleting it, unless ``keep_partial``: a camera session,
    which cannot be recorded again)."""

    def __init__(self, path, sensor, properties: dict, keep_partial: bool = False):
        from necviz.drivers.recordings.native import Recorder

        self.path = Path(path)
        self.output = StreamedOutput(path, keep_partial=keep_partial, flag="--record")
        try:
            self.recorder = Recorder(
                self.output.target, sensor=sensor, properties={k: str(v) for k, v in properties.items()}
            )
        except BaseException:
            self.output.discard()
            raise
        self.closed = False

    @property
    def target(self) -> Path:
        return self.output.target

    def write(self, packet) -> None:
        self.recorder.write(packet)

    def command(self, record) -> None:
        self.recorder.command(record)

    def annotate(self, t_us: int, data: dict) -> None:
        self.recorder.annotate(t_us, data)

    def close(self) -> None:
        """End the file (END chunk, fsync). Raises what writing it raised (a full disk)."""
        if not self.closed:
            self.closed = True
            self.recorder.close()

    def commit(self) -> None:
        """The run succeeded: the file takes its final name."""
        self.close()
        self.output.commit()

    def discard(self) -> str:
        """The run failed: delete (or keep, when ``keep_partial``) the file; returns what happened."""
        try:
            self.close()
        except BaseException:  # noqa: BLE001 - the run's own error is the one reported
            pass
        return self.output.discard()


_LOST = "nothing was written to "
_KEPT = "the recording so far is in "


def recording_target(path) -> Path:
    """Where to stream a recording bound for ``path`` (:class:`StreamedOutput`'s ``target``)."""
    return StreamedOutput(path).target


def commit_recording(target: Path, path) -> None:
    """Move a finished recording from its :func:`recording_target` to ``path`` (no-op when they agree)."""
    if Path(target) != Path(path):
        os.replace(target, _destination(path))


def failure_note(exc: BaseException, notes: list[str]) -> BaseException:
    """``exc`` with ``notes`` (what :meth:`StreamedOutput.discard` did) appended to its one-line message.

    A :class:`NecvizError` keeps its type; an ``OSError`` from writing (a full disk) becomes an
    :class:`OutputError`; anything else (a bug, Ctrl-C) is returned unchanged.
    """
    grouped: dict[str, list[str]] = {}
    for n in notes:
        for prefix in (_LOST, _KEPT):
            if n and n.startswith(prefix):
                grouped.setdefault(prefix, []).append(n[len(prefix) :])
    notes = [n for n in notes if n and not n.startswith((_LOST, _KEPT))]
    if _KEPT in grouped:
        notes.insert(0, f"what was recorded before the failure is kept in {', '.join(grouped[_KEPT])}")
    if _LOST in grouped:
        notes.insert(0, f"nothing was written ({', '.join(grouped[_LOST])})")
    if isinstance(exc, OSError) and not isinstance(exc, (FileNotFoundError, PermissionError)):
        where = f"{exc.filename}: " if exc.filename else ""
        what = exc.strerror or " ".join(str(exc).split())
        return OutputError(f"{where}{what}" + (f"; {'; '.join(notes)}" if notes else ""))
    if not notes or not isinstance(exc, NecvizError):
        return exc
    try:
        new = type(exc)(f"{' '.join(str(exc).split())}; {'; '.join(notes)}")
    except TypeError:
        return exc
    return new


#: the suffix each output flag's file must have
OUTPUT_SUFFIXES = {"--record": (".necrec",), "--json": (".json",), "--video": (".mp4",), "--save": (".rrd",)}


def check_run_files(outputs: dict, viewer, inputs, force: bool) -> None:
    """Everything a dashboard run checks about its files before it opens a camera, a file or a viewer.

    ``outputs`` maps flags to the files the command writes (``{"--record": ..., "--json": ...}``; ``None``:
    not written), ``viewer`` (resolved :class:`~necviz.options.ViewerOptions`) adds its ``--save`` file;
    ``inputs``: the files the run reads. Each output is new (or replaced with ``force``; the ``--save``
    file with the viewer's own ``force``) and has its suffix, no two are one file, none is an input, and
    the disk of a recording that grows for the whole run has room."""
    inputs = [i for i in inputs if i is not None]
    save = viewer.save
    if save is not None:
        check_output(save, "--save", inputs=inputs, force=viewer.force, suffixes=OUTPUT_SUFFIXES["--save"])
    check_distinct({**outputs, "--save": save})
    for flag, path in outputs.items():
        if path is not None:
            check_output(path, flag, inputs=inputs, force=force, suffixes=OUTPUT_SUFFIXES.get(flag))
    check_not_input({**outputs, "--save": save}, inputs)
    for flag, path in (("--record", outputs.get("--record")), ("--save", save)):
        if path is not None:  # a recording grows for the whole run: refuse to start on a full disk
            check_space(path, flag)


__all__ = [
    "OUTPUT_SUFFIXES",
    "check_run_files",
    "Output",
    "OutputError",
    "RECORDING_RESERVE",
    "RecordingFile",
    "StreamedOutput",
    "atomic_output",
    "atomic_write",
    "check_distinct",
    "check_not_input",
    "check_output",
    "check_space",
    "commit_recording",
    "failure_note",
    "free_bytes",
    "low_space",
    "make_folder",
    "new_file_mode",
    "recording_target",
    "same_file",
    "write_failed",
    "write_json",
]
