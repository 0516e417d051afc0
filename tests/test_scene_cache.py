"""The scene cache (:mod:`necviz.drivers.sim.scene_cache`): a replayed rig gives exactly the packets of a fresh
one, and the cache stays within its bound, writes nothing for a run cut short and survives a damaged entry."""

import hashlib
import os

import numpy as np
import pytest

from necviz.core.frames import Frame
from necviz.drivers.sim.rig import RigOptions, SimRig
from necviz.drivers.sim.scene_cache import SceneCache
from necviz.options import SceneOptions

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


def _rig(cache, duration_s=0.2, threads=True, seed=0, **params):
    scene = SceneOptions("tunnel_exit", seed=seed, duration_s=duration_s, params=params).build()
    cams = {f"cam{i}": (float(e), 1.0) for i, e in enumerate(np.geomspace(20, 15_000, 4))}
    return SimRig(scene, cams, seed=seed, options=RigOptions(threads=threads), cache=cache)


def _digest(rig, stop_after=None) -> str:
    h = hashlib.sha256()
    for n, (name, p) in enumerate(rig.packets()):
        if stop_after is not None and n == stop_after:
            break
        h.update(str(name).encode())
        if name is None:
            h.update(np.ascontiguousarray(p.events).tobytes())
        elif isinstance(p, Frame):
            h.update(p.image.tobytes())
            # the events lost at the bus ceiling too: the diagnosis reads them, so the cache must keep them
            truth = p.truth
            for a in (
                truth.mean_irradiance,
                truth.light_t_us,
                truth.light_log,
                truth.lost_t_us,
                truth.lost_on,
                truth.lost_off,
            ):
                h.update(np.ascontiguousarray(a).tobytes())
        else:
            h.update(repr((p.t_us, p.kind)).encode())
    return h.hexdigest()


@pytest.mark.parametrize("threads", [True, False])
def test_a_replay_from_the_cache_gives_the_packets_of_a_fresh_run(tmp_path, threads):
    cache = SceneCache(tmp_path, 2**31)
    fresh = _digest(_rig(None, threads=threads))
    writing = _rig(cache, threads=threads)
    assert _digest(writing) == fresh and writing.cache_written and writing.samples_cached == 0
    reading = _rig(cache, threads=not threads)  # written with threads, read without (and the other way)
    assert _digest(reading) == fresh
    assert reading.samples_cached > 90 and reading.samples_rendered == 0  # nothing rendered: all read
    other = _rig(cache, threads=threads, seed=1)  # another seed is another stream: rendered
    _digest(other)
    assert other.samples_cached == 0 and other.cache_written
    assert len([d for d in os.listdir(tmp_path) if not d.startswith(".")]) == 2


def test_the_cache_keeps_to_its_bound_and_never_writes_a_partial_stream(tmp_path):
    probe = SceneCache(tmp_path / "probe", 2**31)
    _digest(_rig(probe))
    (d,) = os.listdir(tmp_path / "probe")
    one = sum(os.path.getsize(tmp_path / "probe" / d / f) for f in os.listdir(tmp_path / "probe" / d))
    cache = SceneCache(tmp_path / "bounded", int(2.5 * one))  # room for two 0.2 s streams, not three
    for seed in (0, 1, 2):
        _digest(_rig(cache, seed=seed))
    root = tmp_path / "bounded"
    entries = [d for d in os.listdir(root) if not d.startswith(".")]
    size = sum(os.path.getsize(root / d / f) for d in entries for f in os.listdir(root / d))
    assert len(entries) == 2 and size <= cache.max_bytes
    assert cache.open(cache.key(_rig(cache, seed=0)), (260, 346)) is None  # the least recently used went
    assert cache.open(cache.key(_rig(cache, seed=2)), (260, 346)) is not None
    cut = _rig(SceneCache(tmp_path / "cut", 2**31))
    _digest(cut, stop_after=50)  # a run that stops early (Ctrl-C, --duration of a live session)
    assert not cut.cache_written and not [d for d in os.listdir(tmp_path / "cut") if not d.startswith(".")]
    small = _rig(SceneCache(tmp_path / "small", one // 4))  # a stream larger than the bound is not written
    _digest(small)
    assert not small.cache_written and not (tmp_path / "small").exists()


def test_a_damaged_entry_is_rendered_again(tmp_path):
    cache = SceneCache(tmp_path, 2**31)
    fresh = _digest(_rig(cache))
    (entry,) = [tmp_path / d for d in os.listdir(tmp_path) if not d.startswith(".")]
    with open(entry / "images.f32", "r+b") as f:  # truncated (a disk that filled up, say)
        f.truncate(1000)
    again = _rig(cache)
    assert _digest(again) == fresh and again.samples_cached == 0
