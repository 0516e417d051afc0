"""An on-disk cache of a simulated scene's rendered stream, for replayed demos.

What a :class:`~necviz.drivers.sim.rig.SimRig` renders — the scene's irradiance at every sample time, the
lighting trace and the DVS events between samples — depends only on the scene (its class, name, sensor,
duration, seed and parameters), the event model and the sampling settings, never on the cameras or their
controllers. Rendering and the event model are most of the simulator's work (about 60 % of a demo's
simulation), so a second run of the same scene can read them instead: frames are still formed per camera
from the cached irradiance (their exposures depend on the controllers), and everything is bit-identical to
a fresh run (a test compares the packets of both).

Location and size: ``$NECVIZ_CACHE_DIR`` (default ``$XDG_CACHE_HOME/necviz/scenes``, i.e.
``~/.cache/necviz/scenes``), at most ``$NECVIZ_SCENE_CACHE_MB`` MB (default 2048; ``0`` turns the cache
off); least recently used entries are removed to make room, and a stream larger than the bound is never
written. An entry is one directory per key (``images.f32``: the float32 irradiance images in sample
order; ``events.bin``: the events, ``events.idx``: each sample's first event; ``samples.npz``: times and
trace; ``meta.json`` last, written when the run has rendered the whole scene). A run cut short writes
nothing. The key hashes the scene's full description, the models, the sampling and the simulator's source
code, so any change to the simulator is a different key. Clear it by deleting the directory.

About 0.37 GB per simulated second at 346x260 (one image every 2 ms, refined where the light changes
fast): only demos, which are replayed, use it (``necviz demo``); comparisons and sweeps do not.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import uuid
from pathlib import Path

import numpy as np

from necviz.core.events import EVENT_DTYPE

__all__ = ["SceneCache"]

DEFAULT_MB = 2048
_SIM_DIR = Path(__file__).resolve().parent
_code_hash: str | None = None


def _simulator_fingerprint() -> str:
    """sha256 of every source file of the simulator (a change of any invalidates every entry)."""
    global _code_hash
    if _code_hash is None:
        h = hashlib.sha256()
        for path in sorted(_SIM_DIR.rglob("*.py")):
            h.update(str(path.relative_to(_SIM_DIR)).encode())
            h.update(path.read_bytes())
        _code_hash = h.hexdigest()
    return _code_hash


def default_root() -> Path:
    base = os.environ.get("NECVIZ_CACHE_DIR")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "necviz" / "scenes"


class SceneCache:
    """A bounded directory of rendered scene streams (see the module docstring).

    Parameters
    ----------
    root : the directory (default: :func:`default_root`).
    max_bytes : the bound on its size (default ``$NECVIZ_SCENE_CACHE_MB``, else 2048 MB).
    """

    def __init__(self, root: str | os.PathLike | None = None, max_bytes: int | None = None):
        self.root = Path(root) if root is not None else default_root()
        if max_bytes is None:
            max_bytes = int(float(os.environ.get("NECVIZ_SCENE_CACHE_MB", DEFAULT_MB)) * 2**20)
        self.max_bytes = int(max_bytes)

    @classmethod
    def default(cls) -> SceneCache | None:
        """The user's cache, or ``None`` when ``$NECVIZ_SCENE_CACHE_MB`` is 0."""
        cache = cls()
        return cache if cache.max_bytes > 0 else None

    # -- keys -------------------------------------------------------------------------------------------
    def key(self, rig) -> str | None:
        """The entry of ``rig``'s stream, or ``None`` when its scene cannot be described (not a necviz scene)."""
        scene = rig.scene
        cls = type(scene)
        if not cls.__module__.startswith("necviz.drivers.sim"):
            return None  # a user's own scene class: its code is not in the fingerprint
        desc = {
            "scene": f"{cls.__module__}.{cls.__qualname__}",
            "name": scene.name,
            "sensor": [scene.sensor.width, scene.sensor.height],
            "duration_us": int(scene.duration_us),
            "seed": int(scene.seed),
            "params": {k: repr(v) for k, v in sorted(dict(scene.params).items())},
            "dvs": {k: repr(v) for k, v in rig.dvs_params.as_dict().items()},
            "rig_seed": int(rig.seed),
            "sampling": [rig.sample_us, repr(rig.refine_log), rig.min_sample_us],
            "truth": bool(rig.truth),
            "code": _simulator_fingerprint(),
        }
        return hashlib.sha256(json.dumps(desc, sort_keys=True).encode()).hexdigest()[:32]

    # -- reading ----------------------------------------------------------------------------------------
    def open(self, key: str, shape: tuple[int, int]) -> CachedStream | None:
        """The cached stream ``key`` (``None`` when absent or unreadable: then the scene is rendered)."""
        d = self.root / key
        try:
            meta = json.loads((d / "meta.json").read_text())
            if tuple(meta["shape"]) != tuple(shape):
                return None
            stream = CachedStream(d, meta)
            os.utime(d / "meta.json")  # recently used
            return stream
        except (OSError, ValueError, KeyError):
            return None

    # -- writing ----------------------------------------------------------------------------------------
    def writer(self, key: str, shape: tuple[int, int], expected_samples: int) -> CacheWriter | None:
        """A writer for ``key``, or ``None`` when the stream would not fit the bound or the directory is not writable."""
        size = expected_samples * shape[0] * shape[1] * 4
        if size > self.max_bytes:
            return None
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{key}.", dir=self.root))
        except OSError:
            return None
        return CacheWriter(self, key, tmp, shape)

    def _make_room(self, keep: Path) -> None:
        """Remove least recently used entries (and abandoned partial ones) until the cache fits its bound."""
        entries = []
        for d in self.root.iterdir():
            if not d.is_dir():
                continue
            if d.name.startswith("."):  # a partial entry of a run that died
                try:
                    if (os.path.getmtime(d) + 3600) < os.path.getmtime(keep):
                        shutil.rmtree(d, ignore_errors=True)
                except OSError:
                    pass
                continue
            try:
                size = sum(f.stat().st_size for f in d.iterdir())
                used = (d / "meta.json").stat().st_mtime
            except OSError:
                size, used = 0, 0.0
            entries.append((used, size, d))
        total = sum(s for _, s, _ in entries)
        for _used, size, d in sorted(entries):
            if total <= self.max_bytes:
                break
            if d == keep:
                continue
            shutil.rmtree(d, ignore_errors=True)
            total -= size


class CachedStream:
    """A cached stream, read back: the sample at time 0 and the samples of each sample period."""

    def __init__(self, d: Path, meta: dict):
        h, w = meta["shape"]
        n = int(meta["samples"])
        self.images = np.memmap(d / "images.f32", np.float32, "r", shape=(n, h, w))
        with np.load(d / "samples.npz") as z:
            self.times = z["times"]
            self.trace = z["trace"]
        self.events = np.memmap(d / "events.bin", EVENT_DTYPE, "r") if (d / "events.bin").stat().st_size else None
        self.first_event = np.fromfile(d / "events.idx", np.int64)
        self.lost = np.fromfile(d / "lost.idx", np.int64).reshape(-1, 2)
        if self.times.size != n or self.first_event.size != n + 1 or self.lost.shape[0] != n:
            raise ValueError("inconsistent cache entry")
        self.sample_us = int(meta["sample_us"])
        self.pos = 1  # sample 0 is the scene at t = 0

    def first(self):
        """``(L, trace value)`` at t = 0."""
        return np.asarray(self.images[0]), float(self.trace[0])

    def _events(self, i: int) -> np.ndarray:
        a, b = int(self.first_event[i]), int(self.first_event[i + 1])
        if self.events is None or b == a:
            return np.zeros(0, EVENT_DTYPE)
        # a writable copy: a read-only view of the mapped file would be another Numba signature for every
        # kernel that takes events (compiled while streaming, after the warm-up)
        return np.array(self.events[a:b])

    def period(self):
        """The samples of the next sample period, as ``SimRig._render_periods`` gives them (events ready,
        with the cumulative ON / OFF counts lost at the bus ceiling)."""
        out = []
        while self.pos < self.times.size:
            ts = int(self.times[self.pos])
            on, off = (int(v) for v in self.lost[self.pos])
            out.append(
                (ts, np.asarray(self.images[self.pos]), float(self.trace[self.pos]), (self._events(self.pos), on, off))
            )
            self.pos += 1
            if ts % self.sample_us == 0:  # a period ends with its sample on the grid
                break
        return out


class CacheWriter:
    """Appends a run's samples to a partial entry; :meth:`commit` makes it an entry, :meth:`abort` drops it."""

    def __init__(self, cache: SceneCache, key: str, tmp: Path, shape: tuple[int, int]):
        self.cache, self.key, self.tmp, self.shape = cache, key, tmp, shape
        self._images = open(tmp / "images.f32", "wb")  # noqa: SIM115 - closed in commit/abort
        self._events = open(tmp / "events.bin", "wb")  # noqa: SIM115
        self.times: list[int] = []
        self.trace: list[float] = []
        self.first_event = [0]
        self.lost: list[tuple[int, int]] = []  # cumulative ON / OFF counts lost at the bus ceiling, per sample
        self._n_events = 0
        self.failed = False

    def sample(self, t_us: int, lin: np.ndarray, trace: float | None) -> None:
        if self.failed:
            return
        try:
            self._images.write(np.ascontiguousarray(lin, np.float32).tobytes())
        except OSError:
            self.failed = True
            return
        self.times.append(int(t_us))
        self.trace.append(np.nan if trace is None else float(trace))

    def events(self, ev: np.ndarray, lost_on: int = 0, lost_off: int = 0) -> None:
        """The events of the next sample (in sample order, the first sample at t = 0 having none) and the
        cumulative counts the sensor lost at its bus ceiling by then."""
        if self.failed:
            return
        try:
            if ev.size:
                self._events.write(np.ascontiguousarray(ev).tobytes())
        except OSError:
            self.failed = True
            return
        self._n_events += int(ev.size)
        self.first_event.append(self._n_events)
        self.lost.append((int(lost_on), int(lost_off)))

    def commit(self, sample_us: int) -> bool:
        """The run rendered the whole scene: make the entry (False when it could not be written)."""
        self._images.close()
        self._events.close()
        if self.failed or len(self.first_event) != len(self.times) + 1 or len(self.lost) != len(self.times):
            self.abort()
            return False
        try:
            np.savez(self.tmp / "samples.npz", times=np.array(self.times, np.int64), trace=np.array(self.trace))
            np.array(self.first_event, np.int64).tofile(self.tmp / "events.idx")
            np.array(self.lost, np.int64).reshape(-1, 2).tofile(self.tmp / "lost.idx")
            meta = {
                "shape": list(self.shape),
                "samples": len(self.times),
                "sample_us": int(sample_us),
                "id": uuid.uuid4().hex,
            }
            (self.tmp / "meta.json").write_text(json.dumps(meta))
            final = self.cache.root / self.key
            if final.exists():  # another run wrote it meanwhile: keep theirs
                shutil.rmtree(self.tmp, ignore_errors=True)
                return True
            os.replace(self.tmp, final)
            self.cache._make_room(final)
            return True
        except OSError:
            self.abort()
            return False

    def abort(self) -> None:
        for f in (self._images, self._events):
            if not f.closed:
                f.close()
        shutil.rmtree(self.tmp, ignore_errors=True)
