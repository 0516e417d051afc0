"""Running a sweep on Dask ``distributed``: the cluster, the task loop, progress, retries and Ctrl-C.

**Cluster.** By default an embedded :class:`distributed.LocalCluster` of worker *processes*, one
thread each, as many as there are cores (``workers``), its scheduler and dashboard bound to
127.0.0.1, every worker started with ``NUMBA_NUM_THREADS=1`` (and one OpenMP/BLAS thread) so N
workers use N cores. ``scheduler="tcp://HOST:PORT"`` connects to a running cluster instead (any
Dask deployment: ``dask scheduler`` + ``dask worker``, SSH, Kubernetes, Slurm through
dask-jobqueue); its workers need necviz installed, and the client needs the sweep's files.

**Tasks.** One task per run: :func:`necviz.sweeps.worker.execute` (a plain top-level function) on
the run's plain-dict spec, keyed ``necviz-run-<hash>``. The worker returns the row and the trace
as Parquet bytes; the client writes them into ``OUT/runs/`` atomically as each task completes
(:class:`~necviz.sweeps.store.Store`), so finished runs are on disk whatever happens next.

**Failures and retries.** A run that raises is a row with ``status = "failed"`` (the task itself
succeeds). A worker that dies (killed, out of memory, a crash in native code) has its task
rescheduled by Dask on another worker; a task whose workers died more than ``retries`` times (the
scheduler's ``distributed.scheduler.allowed-failures``, set for the embedded cluster; an
external scheduler uses its own setting) raises ``KilledWorker`` and is written as failed.

**Ctrl-C** (or SIGTERM) cancels the tasks not yet finished, closes the embedded cluster, keeps
every row already written and says how to resume; ``--resume`` then runs only the missing rows.
"""

from __future__ import annotations

import importlib.util
import logging
import math
import os
import sys
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from necviz.core.errors import NecvizError, ParameterError
from necviz.sweeps.spec import Plan
from necviz.sweeps.store import Store, SweepDirError, git_revision, machine, now, prepare_out, versions
from necviz.sweeps.worker import failed_row

WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
DEFAULT_DASHBOARD = "127.0.0.1:8787"


class ClusterError(NecvizError):
    """The cluster could not be started or reached."""


@dataclass
class SweepResult:
    """What one ``sweep run`` did (also the ``--json`` output)."""

    out: str
    runs: int
    skipped: int = 0
    ok: int = 0
    failed: int = 0
    interrupted: bool = False
    workers: int = 0
    scheduler: str = ""
    dashboard: str | None = None
    wall_s: float = 0.0  # first submission to last row written
    startup_s: float = 0.0  # cluster start (or connection)
    run_s: float = 0.0  # summed run time on the workers (this session)
    warmup_s: float = 0.0  # summed warm-up time
    write_s: float = 0.0  # time the client spent writing rows
    timeline: list = field(default_factory=list)  # per run: (worker, started, finished on the worker)

    @property
    def written(self) -> int:
        return self.ok + self.failed

    @property
    def left(self) -> int:
        return self.runs - self.skipped - self.written

    def as_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "timeline"}
        d.update(written=self.written, left=self.left)
        return d


# -- the cluster ---------------------------------------------------------------------------------
def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _dashboard_link(client) -> str | None:
    try:
        if "dashboard" not in (client.scheduler_info().get("services") or {}):
            return None
        return client.dashboard_link
    except Exception:  # noqa: BLE001 - a link is a convenience only
        return None


@contextmanager
def connect(
    workers: int | None = None,
    scheduler: str | None = None,
    dashboard: str | None = DEFAULT_DASHBOARD,
    retries: int = 3,
    wait_workers_s: float = 120.0,
):
    """A :class:`distributed.Client`: on an embedded cluster (closed on exit) or a running scheduler."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="15s", set_as_default=False)
        except (OSError, TimeoutError) as e:
            raise ClusterError(f"--scheduler: cannot reach {scheduler} ({' '.join(str(e).split())[:160]})") from None
        try:
            client.wait_for_workers(1, timeout=wait_workers_s)
        except (TimeoutError, OSError):
            client.close()
            raise ClusterError(f"--scheduler: {scheduler} has no workers (waited {wait_workers_s:g} s)") from None
        try:
            yield client
        finally:
            client.close()
        return
    if dashboard and importlib.util.find_spec("bokeh") is None:
        dashboard = None  # Dask serves its dashboard with bokeh (pip install bokeh)
    # The scheduler always runs an HTTP server (health and metrics routes); without a dashboard it
    # gets a random port on 127.0.0.1, never the default of every interface.
    # worker-saturation 1.0: a worker holds only the run it is running, so a worker that dies takes
    # only that run with it (counted against its retries), not the next one queued behind it.
    # Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also switches off glibc's dynamic
    # mmap threshold: every image-sized array is then mmap'd and unmapped, and the page faults cost
    # the simulator about as much system time as its own work (measured: 0.8 s on a 1.3 s run). The
    # workers get glibc's defaults instead.
    spawn_env = {
        k: v
        for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {}).items()
        if k != "MALLOC_TRIM_THRESHOLD_"
    }
    with (
        dask.config.set(
            {
                "distributed.scheduler.allowed-failures": int(retries),
                "distributed.nanny.pre-spawn-environ": spawn_env,
                "distributed.scheduler.worker-saturation": 1.0,
                "distributed.worker.daemon": True,
                "distributed.admin.tick.limit": "30s",
            }
        ),
        warnings.catch_warnings(),
    ):
        warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")  # Dask then picks another
        try:
            cluster = LocalCluster(
                n_workers=workers or default_workers(),
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=dashboard or "127.0.0.1:0",
                scheduler_kwargs={"dashboard": bool(dashboard)},
                silence_logs=logging.CRITICAL,
                env=dict(WORKER_ENV),
            )
        except (OSError, RuntimeError, TimeoutError) as e:
            raise ClusterError(f"cannot start a local Dask cluster: {' '.join(str(e).split())[:200]}") from None
        client = Client(cluster, set_as_default=False)
        from necviz.sweeps.worker import IgnoreInterrupt

        client.register_plugin(IgnoreInterrupt())
        try:
            yield client
        finally:
            try:
                client.close()
            finally:
                cluster.close()


def _check_dashboard(text: str | None) -> str | None:
    if text is None or str(text).lower() in ("off", "none", ""):
        return None
    host, sep, port = str(text).rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ParameterError(f"--dashboard expects HOST:PORT or off, got {text!r}")
    return str(text)


# -- the manifest --------------------------------------------------------------------------------
def _manifest(plan: Plan, store: Store, resume: bool) -> dict:
    grid = [{"hash": r.hash, "spec": r.spec} for r in plan.runs]
    if resume:
        old = store.manifest()
        before = {g["hash"] for g in old.get("grid", [])}
        dropped = before - set(plan.hashes)
        if dropped:
            raise SweepDirError(
                f"--resume: {len(dropped)} of the {len(before)} runs of the sweep in {store.root} "
                f"are not in {plan.source} (the file or a file it names changed); use a new --out "
                f"or --force to start over"
            )
        m = dict(old)
        m.update(
            grid=grid,
            sweep_file=plan.source,
            sweep_text=plan.text,
            sweep=plan.data,
            metrics=plan.metrics,
            counts=plan.counts(),
            updated=now(),
        )
        m.setdefault("sessions", [])
        return m
    return {
        "format": "necviz-sweep/1",
        "name": plan.name,
        "created": now(),
        "updated": now(),
        "sweep_file": str(plan.source),
        "sweep_text": plan.text,
        "sweep": plan.data,
        "metrics": plan.metrics,
        "counts": plan.counts(),
        "grid": grid,
        "versions": versions(),
        "git": git_revision(),
        "machine": machine(),
        "sessions": [],
    }


# -- progress --------------------------------------------------------------------------------------
def _clock(s: float) -> str:
    if not math.isfinite(s):
        return "–"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m{sec:02d}s" if h else (f"{m}m{sec:02d}s" if m else f"{sec}s")


class Progress:
    """A live line on a terminal (``\\r``), a line every ``every_s`` seconds otherwise."""

    def __init__(self, total: int, skipped: int, stream, every_s: float = 10.0, width: int = 24):
        self.total, self.skipped, self.stream = total, skipped, stream
        self.tty = bool(stream is not None and hasattr(stream, "isatty") and stream.isatty())
        self.every_s, self.width = every_s, width
        self.t0 = time.perf_counter()
        self._last = -math.inf
        self._len = 0

    def line(self, ok: int, failed: int, running: int) -> str:
        done = self.skipped + ok + failed
        left = self.total - done
        frac = done / self.total if self.total else 1.0
        fill = int(round(frac * self.width))
        el = time.perf_counter() - self.t0
        made = ok + failed
        eta = el / made * left if made else math.inf
        return (
            f"sweep [{'#' * fill}{'.' * (self.width - fill)}] {done}/{self.total} done · {failed} failed · "
            f"{running} running · {left} left · {_clock(el)} elapsed · ETA {_clock(eta) if left else '0s'}"
        )

    def update(self, ok, failed, running, final: bool = False) -> None:
        if self.stream is None:
            return
        t = time.perf_counter()
        if not final and t - self._last < (0.5 if self.tty else self.every_s):
            return
        self._last = t
        text = self.line(ok, failed, running)
        if self.tty:
            pad = max(0, self._len - len(text))
            print("\r" + text + " " * pad, end="\n" if final else "", file=self.stream, flush=True)
            self._len = len(text)
        else:
            print(text, file=self.stream, flush=True)


# -- running ---------------------------------------------------------------------------------------
def _warmup_spec(plan: Plan) -> dict:
    """A short run of every controller of the sweep: loads (or compiles) each worker's Numba kernels."""
    return {
        "scenario": "static_lab",
        "seed": 0,
        "duration_s": 0.06,
        "scenario_params": {},
        "controllers": plan.controllers,
        "controller_params": {},
        "profile": None,
        "sim": {},
        "sift": False,
    }


def _error_text(exc: BaseException, retries: int | None) -> str:
    name = type(exc).__name__
    if name == "KilledWorker":
        limit = f"{retries} retries" if retries is not None else "the scheduler's allowed-failures"
        return f"KilledWorker: the worker running it died each time it was tried ({limit})"
    return f"{name}: {' '.join(str(exc).split())[:500]}"


@dataclass(frozen=True)
class SweepOptions:
    """How a sweep runs: where, whether it continues an earlier one, how often a lost run is tried
    again (validated here, once).

    Parameters
    ----------
    workers : int, optional
        Worker processes of the embedded cluster (>= 1; default: one per core).
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a running Dask cluster to use instead of an embedded one.
    resume : bool
        Run only the runs ``out`` does not hold yet.
    force : bool
        Delete the rows of the sweep in ``out`` and start over.
    retry_failed : bool
        With ``resume``: also run again the runs that failed.
    retries : int
        Reschedule a run whose worker died up to this many times (0..100), then record it failed
        (embedded cluster; a running scheduler uses its own ``allowed-failures``).
    dashboard : str, optional
        ``HOST:PORT`` of the embedded cluster's Dask dashboard; ``None`` or ``"off"``: none (kept as ``None``).
    poll_s : float
        Seconds between looks at the finished tasks when none was ready (> 0).

    Raises
    ------
    ParameterError
        Workers or retries out of range, both ``workers`` and ``scheduler``, ``retry_failed``
        without ``resume``, a dashboard that is not ``HOST:PORT`` or a non-positive ``poll_s``.
    """

    workers: int | None = None
    scheduler: str | None = None
    resume: bool = False
    force: bool = False
    retry_failed: bool = False
    retries: int = 3
    dashboard: str | None = DEFAULT_DASHBOARD
    poll_s: float = 0.05

    def __post_init__(self) -> None:
        workers, retries = self.workers, self.retries
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ParameterError(f"--workers must be a whole number >= 1, got {workers!r}")
        if workers is not None and self.scheduler:
            raise ParameterError("give either --workers (an embedded cluster) or --scheduler (a running one), not both")
        if isinstance(retries, bool) or not isinstance(retries, int) or not 0 <= retries <= 100:
            raise ParameterError(f"--retries must be a whole number in [0, 100], got {retries!r}")
        if self.retry_failed and not self.resume:
            raise ParameterError("--retry-failed runs the failed runs of a sweep again: it needs --resume")
        object.__setattr__(self, "dashboard", _check_dashboard(self.dashboard))
        p = self.poll_s
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not (math.isfinite(p) and p > 0):
            raise ParameterError(f"poll_s must be a positive number of seconds, got {p!r}")


def run_sweep(plan: Plan, out, options: SweepOptions | None = None, *, client=None, stream=...) -> SweepResult:
    """Run every run of ``plan`` not yet in ``out`` (see the module docstring); returns what happened.

    Parameters
    ----------
    plan : Plan
        The expanded sweep (:func:`necviz.sweeps.load_plan`).
    out : str or path
        The sweep folder: new or empty, or one to resume (``options.resume``).
    options : SweepOptions, optional
        Where and how to run (default: ``SweepOptions()``, an embedded cluster of one worker per core).
    client : distributed.Client, optional
        An existing client to use (tests, notebooks) instead of ``options.scheduler`` or an
        embedded cluster.
    stream : text stream, optional
        Where progress goes (default: standard error; ``None``: nowhere).

    Returns
    -------
    SweepResult

    Raises
    ------
    ParameterError
        ``options`` that is not a :class:`SweepOptions`, or a sweep that reads a file it would write.
    KeyboardInterrupt
        After a clean stop (Ctrl-C): every finished row is kept.
    """
    opts = SweepOptions() if options is None else options
    if not isinstance(opts, SweepOptions):
        raise ParameterError(f"options must be a SweepOptions, got {type(opts).__name__}")
    stream = sys.stderr if stream is ... else stream
    resume, force, retry_failed = opts.resume, opts.force, opts.retry_failed
    _check_inputs(plan, out)
    store = prepare_out(out, resume=resume, force=force)
    store.lock()
    try:
        manifest = _manifest(plan, store, resume)
        store.write_manifest(manifest)
        if not (store.root / "sweep.toml").exists():
            from necviz.outputs import atomic_write

            with atomic_write(store.root / "sweep.toml") as f:
                f.write(plan.text)
        done = store.done()
        damaged = store.check_rows(done & set(plan.hashes))  # a damaged row is not a finished run
        if damaged and stream is not None:
            h, why = next(iter(damaged.items()))
            print(
                f"sweep: {len(damaged)} result row{'s' if len(damaged) > 1 else ''} damaged "
                f"({store.row_path(h).name}: {why}; kept as .damaged); running {'them' if len(damaged) > 1 else 'it'} "
                "again",
                file=stream,
            )
        for h in damaged:  # set aside, not deleted: nothing a user had is thrown away
            path = store.row_path(h)
            os.replace(path, path.with_name(path.name + ".damaged"))
        done -= set(damaged)
        redo = set()
        if retry_failed and done:
            rows = store.read_rows(done & set(plan.hashes), columns=["hash", "status"], skip_bad=True)
            redo = {r["hash"] for r in rows if r.get("status") != "ok"} | set(store.unreadable)
        todo = [r for r in plan.runs if r.hash not in done or r.hash in redo]
        res = SweepResult(out=str(store.root), runs=len(plan.runs), skipped=len(plan.runs) - len(todo))
        session = {"started": now(), "resume": resume, "runs_to_do": len(todo)}
        stopped = False
        manifest["sessions"].append(session)
        try:
            if todo:
                _execute(plan, store, todo, res, opts, client=client, stream=stream)
        except BaseException as e:
            res.interrupted = isinstance(e, KeyboardInterrupt)
            stopped = True
            raise
        finally:
            session.update(
                finished=now(),
                ok=res.ok,
                failed=res.failed,
                interrupted=res.interrupted,
                workers=res.workers,
                scheduler=res.scheduler,
                wall_s=round(res.wall_s, 3),
            )
            manifest["updated"] = now()
            try:
                store.write_manifest(manifest)
            except OSError:
                pass
            if stream is not None and stopped and res.left:
                print(
                    f"{'interrupted' if res.interrupted else 'stopped'}: {res.skipped + res.written} of "
                    f"{res.runs} runs are in {store.root}; "
                    f"`necviz sweep run {plan.source} --out {store.root} --resume` runs the other {res.left}",
                    file=stream,
                    flush=True,
                )
    finally:
        store.unlock()
    return res


def _execute(plan, store, todo, res, opts: SweepOptions, *, client, stream):
    workers, scheduler, retries, dashboard = opts.workers, opts.scheduler, opts.retries, opts.dashboard
    t_start = time.perf_counter()
    ctx = _existing(client) if client is not None else connect(workers, scheduler, dashboard, retries)
    with ctx as cl:
        res.startup_s = time.perf_counter() - t_start
        nthreads = cl.nthreads()
        res.workers = len(nthreads)
        res.scheduler = scheduler or getattr(cl.scheduler, "address", "") or ""
        embedded_off = client is None and not scheduler and (not dashboard or importlib.util.find_spec("bokeh") is None)
        res.dashboard = None if embedded_off else _dashboard_link(cl)
        if stream is not None:
            where = (
                f"{scheduler}"
                if scheduler
                else ("the given client" if client is not None else "an embedded local cluster")
            )
            print(
                f"sweep: {len(todo)} runs to do ({res.skipped} already in {store.root}) on {res.workers} "
                f"worker{'s' if res.workers != 1 else ''} ({where})",
                file=stream,
                flush=True,
            )
            if res.dashboard:
                print(f"Dask dashboard: {res.dashboard}", file=stream, flush=True)
        limit = retries if client is None and not scheduler else None  # else the scheduler's own setting
        _loop(plan, store, todo, res, cl, nthreads, limit, stream, opts.poll_s)


@contextmanager
def _existing(client):
    yield client


def _loop(plan, store, todo, res, client, nthreads, retries, stream, poll_s):
    import uuid

    from distributed import as_completed

    from necviz.sweeps.worker import execute

    warm = _warmup_spec(plan)
    session = uuid.uuid4().hex[:8]  # keys unique per session: a resubmitted run never reuses a finished key
    t0 = time.perf_counter()
    task_list = [{"hash": r.hash, "spec": r.spec, "columns": r.columns, "warmup": warm} for r in todo]
    futures = client.map(
        execute, task_list, key=[f"necviz-run-{r.hash}-{session}" for r in todo], pure=False, retries=0
    )  # one message for the whole grid, in grid order
    tasks = {f.key: t for f, t in zip(futures, task_list, strict=True)}
    progress = Progress(res.runs, res.skipped, stream)
    pending = {f.key: f for f in futures}
    with client.as_current():  # as_completed finds the client through the context
        ac = as_completed(futures)
    last_poll, running = 0.0, 0
    try:
        while pending:
            batch = ac.next_batch(block=False) if ac.has_ready() else []
            for fut in batch:
                task = tasks.pop(fut.key, None)
                pending.pop(fut.key, None)
                if task is None:
                    continue
                _collect(fut, task, store, res, retries)
                fut.release()
            now_ = time.perf_counter()
            if now_ - last_poll > 1.0:
                last_poll = now_
                running = _running(client, nthreads, len(pending))
            progress.update(res.ok, res.failed, min(running, len(pending)))
            if not batch:
                time.sleep(poll_s)
        res.wall_s = time.perf_counter() - t0
        progress.update(res.ok, res.failed, 0, final=True)
    except KeyboardInterrupt:
        res.wall_s = time.perf_counter() - t0
        progress.update(res.ok, res.failed, 0, final=True)
        try:
            client.cancel(list(pending.values()), force=True)
        except Exception:  # noqa: BLE001 - the cluster is closed next anyway
            pass
        raise


def _running(client, nthreads: dict, pending: int) -> int:
    try:
        proc = client.processing()
        return sum(min(len(keys), nthreads.get(w, 1)) for w, keys in proc.items())
    except Exception:  # noqa: BLE001 - progress only
        return min(pending, sum(nthreads.values()))


def _collect(fut, task, store: Store, res: SweepResult, retries: int) -> None:
    """Write a finished task's row (or a failed row for a task that could not finish)."""
    h = task["hash"]
    if fut.status == "finished":
        out = fut.result()
        t = time.perf_counter()
        store.write_run(h, out["row"], out["trace"])
        res.write_s += time.perf_counter() - t
        if out["status"] == "ok":
            res.ok += 1
        else:
            res.failed += 1
        res.run_s += out["wall_s"] or 0.0
        res.warmup_s += out.get("warmup_s") or 0.0
        res.timeline.append((out["worker"], out["started"], out["started"] + (out["wall_s"] or 0.0)))
        return
    if fut.status == "cancelled":
        raise ClusterError(
            f"the scheduler dropped run {h} (was the cluster shut down?); "
            f"{res.written} rows were written this session, --resume runs the rest"
        )
    exc = fut.exception()
    store.write_run(h, failed_row(task, _error_text(exc, retries)), None)
    res.failed += 1


def _check_inputs(plan: Plan, out) -> None:
    """The files a sweep writes (or deletes with ``--force``) in ``OUT`` may not be any it reads."""
    from necviz.outputs import check_not_input
    from necviz.sweeps.store import MANIFEST

    root = Path(out)
    inputs = {plan.source}
    for r in plan.runs:
        for key in ("scenario", "profile"):
            v = r.spec.get(key)
            if isinstance(v, str) and v not in inputs and Path(v).is_file():
                inputs.add(v)
    for name in (MANIFEST, "sweep.toml"):
        check_not_input({"--out": root / name}, sorted(inputs))


# -- status ------------------------------------------------------------------------------------------
def status(out) -> dict:
    """Counts of a sweep folder: runs in the grid, ok, failed, missing; the last session."""
    store = Store(out)
    m = store.manifest()
    grid = [g["hash"] for g in m.get("grid", [])]
    done = store.done()
    rows = store.read_rows(done & set(grid), columns=["hash", "status", "error", "wall_s"], skip_bad=True)
    ok = sum(r.get("status") == "ok" for r in rows)
    failed = [r for r in rows if r.get("status") != "ok"]
    errors: dict[str, int] = {}
    for r in failed:
        key = (r.get("error") or "?").split(":", 1)[0]
        errors[key] = errors.get(key, 0) + 1
    wall = [r["wall_s"] for r in rows if r.get("wall_s") is not None]
    return {
        "out": str(store.root),
        "name": m.get("name"),
        "sweep_file": m.get("sweep_file"),
        "runs": len(grid),
        "ok": ok,
        "failed": len(failed),
        "missing": len(grid) - len(rows),
        "errors": errors,
        "run_s_total": sum(wall),
        "run_s_mean": (sum(wall) / len(wall)) if wall else None,
        "sessions": len(m.get("sessions", [])),
        "last_session": (m.get("sessions") or [None])[-1],
        "git": m.get("git"),
        "created": m.get("created"),
        "updated": m.get("updated"),
        "failed_runs": [{"hash": r["hash"], "error": r.get("error")} for r in failed[:20]],
        "unreadable": dict(store.unreadable),
        "unreadable_note": store.unreadable_note(m.get("sweep_file")),
    }


__all__ = [
    "ClusterError",
    "DEFAULT_DASHBOARD",
    "Progress",
    "SweepOptions",
    "SweepResult",
    "WORKER_ENV",
    "connect",
    "default_workers",
    "run_sweep",
    "status",
]
