"""What a Dask worker runs: :func:`execute`, a plain top-level function taking and returning plain data.

The task is ``{"hash", "spec", "columns", "warmup"}``; the worker runs the spec with
:func:`necviz.runs.run_spec` and returns the finished row and per-frame trace as Parquet bytes
(built on the worker, so the client only writes bytes to disk). A run that raises becomes a row
with ``status = "failed"`` and its error; it never fails the task, so Dask only retries tasks
whose worker died.

Once per worker process (:func:`prepare`, on its first task) the process is set up for one run at
a time on one core: one Numba thread (``NUMBA_NUM_THREADS=1`` in the embedded cluster's
environment, and ``numba.set_num_threads(1)`` for workers started elsewhere), one OpenCV thread,
the simulator on the run's own thread (``RigOptions(threads=False)``; the same events),
glibc's heap for image-sized arrays (:func:`_heap_allocations`, on workers started with Dask's
``MALLOC_TRIM_THRESHOLD_``), and a warm-up run (a short run of every controller of the sweep) so that loading the compiled
Numba kernels from their on-disk cache is not counted in the first run's time.

Row columns (one row per Parquet file): ``hash``, ``status`` (``ok``/``failed``), ``error``,
``traceback``, the spec's columns (:func:`necviz.sweeps.spec.spec_columns`), ``spec_json`` (the
exact spec, for ``sweep show``), ``sim_duration_s`` (the simulated length), timing (``wall_s``:
the run alone, ``warmup_s`` on a worker's first task, ``started_at``, ``finished_at``), where it
ran (``worker``: host:pid) and every scalar in the controller's result: numbers (metrics; their
names are listed in the schema metadata key ``necviz.metrics``), tables flattened with ``.``
(``failure_causes.overexposed``), short lists as JSON text. Per-frame records (the result's
``frames_detail``) go to the trace file.
"""

from __future__ import annotations

import io
import json
import math
import os
import socket
import sys
import threading
import time
import traceback

ROW_FORMAT = "necviz-sweep-row/1"
TRACE_SKIP = {"frames_detail", "exposure_trace_us", "gain_trace", "frame_starts_us"}
MAX_LIST = 64  # longer lists are traces, not row values


def _heap_allocations() -> bool:
    """Undo Dask's ``MALLOC_TRIM_THRESHOLD_`` on a worker someone else started (glibc only).

    Setting that variable switches off glibc's dynamic mmap threshold, so every array above 128 KiB
    (every image) is mmap'd and unmapped again and its pages fault in anew: the simulator then
    spends about as long in the kernel as in its own work. Here arrays up to 64 MiB come from the
    heap again, and the heap is trimmed only when 128 MiB are free at its top.
    """
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ or not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3
        return bool(libc.mallopt(m_mmap_threshold, 64 << 20) and libc.mallopt(m_trim_threshold, 128 << 20))
    except (OSError, AttributeError):
        return False


_lock = threading.Lock()
_prepared = False
_warmup_s: float | None = None


def prepare(warmup: dict | None, serial: bool = True) -> float | None:
    """Set this process up for sweep runs once; returns the warm-up time on the first call, else None."""
    global _prepared, _warmup_s
    with _lock:
        if _prepared:
            return None
        os.environ.setdefault("NUMBA_NUM_THREADS", "1")
        _heap_allocations()
        try:
            import cv2

            cv2.setNumThreads(1)
        except Exception:  # noqa: BLE001 - OpenCV threads are an optimisation only
            pass
        t0 = time.perf_counter()
        if warmup:
            from necviz.runs import run_spec

            try:
                run_spec(warmup, threads=False if serial else None)
            except Exception:  # noqa: BLE001 - a failing warm-up shows up again in the real run
                pass
        _warmup_s = time.perf_counter() - t0
        _prepared = True
        return _warmup_s


try:
    from distributed.diagnostics.plugin import WorkerPlugin as _WorkerPlugin
except ImportError:  # pragma: no cover - distributed is a dependency
    _WorkerPlugin = object


class IgnoreInterrupt(_WorkerPlugin):
    """Makes the embedded cluster's worker processes ignore SIGINT.

    A terminal's Ctrl-C reaches the whole process group; the client stops the sweep and closes the
    workers itself, so a worker must not die of the same signal (with a traceback) first. Run on
    the worker's event loop, which is its main thread, where signal handlers are set.
    """

    name = "necviz-ignore-sigint"

    def setup(self, worker):
        import signal

        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def _threads() -> None:
    try:
        import numba

        if numba.get_num_threads() != 1:
            numba.set_num_threads(1)  # thread-local: Dask runs tasks on its executor thread
    except Exception:  # noqa: BLE001
        pass


def execute(task: dict) -> dict:
    """Run one task (see the module docstring); returns ``{"hash", "status", "error", "wall_s", ...}``
    with the row and trace as Parquet bytes."""
    warm = prepare(task.get("warmup"), task.get("serial", True))
    _threads()
    from necviz.runs import run_spec

    spec = task["spec"]
    started = time.time()
    t0 = time.perf_counter()
    result, error, tb = None, None, None
    try:
        result = run_spec(spec, threads=False if task.get("serial", True) else None)
    except Exception as e:  # noqa: BLE001 - recorded in the row, the sweep goes on
        error = f"{type(e).__name__}: {' '.join(str(e).split())}"
        tb = traceback.format_exc()
    wall = time.perf_counter() - t0
    where = f"{socket.gethostname()}:{os.getpid()}"
    row = build_row(task, result, error, tb, wall=wall, warmup_s=warm, started=started, worker=where)
    trace = None
    if result is not None:
        (ctrl,) = spec["controllers"]
        trace = trace_bytes(result["results"][ctrl].get("frames_detail") or [], task["hash"])
    return {
        "hash": task["hash"],
        "status": row["status"],
        "error": error,
        "wall_s": wall,
        "warmup_s": warm,
        "started": started,
        "worker": where,
        "row": row_bytes(row),
        "trace": trace,
    }


def flatten_result(res: dict) -> tuple[dict, list[str]]:
    """A controller's result -> (flat columns, names of the numeric ones)."""
    cols, metrics = {}, []

    def add(key, v):
        if isinstance(v, dict):
            for k, x in v.items():
                add(f"{key}.{k}", x)
        elif isinstance(v, bool):
            cols[key] = v
        elif isinstance(v, (int, float)) or v is None:
            cols[key] = None if isinstance(v, float) and not math.isfinite(v) else v
            metrics.append(key)
        elif isinstance(v, str):
            cols[key] = v
        elif (
            isinstance(v, (list, tuple))
            and len(v) <= MAX_LIST
            and all(x is None or isinstance(x, (bool, int, float, str)) for x in v)
        ):
            cols[key] = json.dumps([None if isinstance(x, float) and not math.isfinite(x) else x for x in v])
        # longer lists and anything else are traces (the trace file) or not row data

    for k, v in res.items():
        if k not in TRACE_SKIP:
            add(k, v)
    return cols, metrics


def build_row(task: dict, result: dict | None, error, tb, *, wall, warmup_s, started, worker) -> dict:
    """The row of a run as ``{column: value}`` plus its metric names under ``"__metrics__"``."""
    spec = task["spec"]
    row = {
        "hash": task["hash"],
        "status": "ok" if error is None else "failed",
        "error": error,
        "traceback": tb,
        **task["columns"],
        "spec_json": json.dumps(spec, sort_keys=True),
        "sim_duration_s": None,
        "wall_s": wall,
        "warmup_s": warmup_s,
        "started_at": _iso(started),
        "finished_at": _iso(time.time()),
        "worker": worker,
    }
    metrics: list[str] = []
    if result is not None:
        (ctrl,) = spec["controllers"]
        row["sim_duration_s"] = result.get("duration_s")
        cols, keys = flatten_result(result["results"][ctrl])
        rename = {k: (k if k not in row else f"metric.{k}") for k in cols}  # a metric never hides a spec column
        for k, v in cols.items():
            row[rename[k]] = v
        metrics = [rename[k] for k in keys]
    row["__metrics__"] = metrics
    return row


def failed_row(task: dict, error: str) -> bytes:
    """A failed row written by the client (the task itself could not finish: its workers died)."""
    row = build_row(task, None, error, None, wall=None, warmup_s=None, started=time.time(), worker=None)
    return row_bytes(row)


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t)) + f".{int((t % 1) * 1000):03d}"


def row_bytes(row: dict) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    row = dict(row)
    metrics = row.pop("__metrics__", [])
    arrays, names = [], []
    for k, v in row.items():
        names.append(k)
        if v is None:
            arrays.append(pa.nulls(1))
        else:
            arrays.append(pa.array([v]))
    meta = {b"necviz.format": ROW_FORMAT.encode(), b"necviz.metrics": json.dumps(metrics).encode()}
    table = pa.Table.from_arrays(arrays, names=names).replace_schema_metadata(meta)
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def trace_bytes(frames: list[dict], run_hash: str) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist(frames) if frames else pa.table({})
    table = table.replace_schema_metadata({b"necviz.run": run_hash.encode()})
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


__all__ = [
    "IgnoreInterrupt",
    "execute",
    "flatten_result",
    "prepare",
    "row_bytes",
    "trace_bytes",
]
