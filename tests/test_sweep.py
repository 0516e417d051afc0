"""``necviz sweep``: grids on a real Dask cluster, Parquet rows, resume, failures, retries, report, show.

Tiny scenes (0.2 s of ``tunnel_exit``) keep the whole file near a minute on two cores. One local
cluster of two worker processes serves most tests; one test starts a separate ``dask scheduler``
+ ``dask worker`` pair and connects with ``--scheduler``; one runs the command in a subprocess and
interrupts it as a terminal's Ctrl-C would (SIGINT to its process group).
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from necviz.commands.cli import main
from necviz.sweeps import SweepOptions, load_plan, run_sweep
from necviz.sweeps.spec import spec_hash
from necviz.sweeps.store import Store

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SWEEP = """
name = "tiny"
seeds = "0..1"
duration_s = 0.2
controllers = ["nec", "fixed"]
[[scenarios]]
name = "tunnel_exit"
params = { exit_s = [0.1, 5.0] }   # 5 s lies outside a 0.2 s run: those runs raise
"""

GOOD = """
seeds = "0..1"
duration_s = 0.2
controllers = ["fixed", "nec"]
scenarios = [{ name = "tunnel_exit", params = { exit_s = 0.1 } }]
"""


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def client():
    from necviz.sweeps.engine import connect

    with connect(workers=2, dashboard=None) as c:
        yield c


@pytest.fixture(scope="module")
def first(client, tmp_path_factory):
    """The tiny sweep, run once on the local cluster: (plan, folder, result)."""
    d = tmp_path_factory.mktemp("sweep")
    plan = load_plan(_write(d / "tiny.toml", SWEEP))
    res = run_sweep(plan, d / "out", client=client, stream=None)
    return plan, d / "out", res


def _ok_rows(out) -> dict:
    return {r["hash"]: r for r in Store(out).read_rows() if r["status"] == "ok"}


# -- the grid -------------------------------------------------------------------------------------
def test_rows_equal_grid_and_failures_are_recorded(first):
    plan, out, res = first
    assert len(plan.runs) == 8  # 2 exit_s × 2 controllers × 2 seeds
    rows = Store(out).read_rows()
    assert sorted(r["hash"] for r in rows) == sorted(plan.hashes)
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 4 and all(r["scenario_params.exit_s"] == 5.0 for r in failed)
    assert all("exit_s" in r["error"] and r["error"].startswith("ParameterError") for r in failed)
    assert (res.ok, res.failed, res.written, res.left) == (4, 4, 8, 0)
    for r in rows:
        if r["status"] == "ok":
            assert r["frames"] == 10 and r["error"] is None  # 0.2 s at 50 frames/s
            assert "saturated_frames_50" in r["__metrics__"] and "recovery_ms" in r["__metrics__"]
            trace = pq.read_table(Store(out).trace_path(r["hash"]))
            assert trace.num_rows == r["frames"]
            assert sum(trace.column("saturated").to_pylist()) == r["saturated_frames_50"]
    m = json.loads((out / "manifest.json").read_text())
    assert [g["hash"] for g in m["grid"]] == plan.hashes
    assert m["versions"]["distributed"] and m["machine"]["cpu_count"]
    assert (out / "sweep.toml").read_text() == SWEEP
    assert not list((out / "runs").glob(".*"))  # no temporary files left


def test_same_spec_gives_same_hash_and_identical_metrics_on_a_separate_scheduler(first, tmp_path):
    """A `dask scheduler` + `dask worker` pair on 127.0.0.1, connected with --scheduler."""
    _, out_a, _ = first
    plan = load_plan(_write(tmp_path / "good.toml", GOOD))
    rows_a = _ok_rows(out_a)
    assert set(plan.hashes) == set(rows_a)  # the same runs from another file: the same keys
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    sched = subprocess.Popen(
        [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    worker = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dask",
            "worker",
            f"tcp://127.0.0.1:{port}",
            "--host",
            "127.0.0.1",
            "--nthreads",
            "1",
            "--nworkers",
            "1",
            "--no-dashboard",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        out_b = tmp_path / "b"
        rc = main(
            [
                "sweep",
                "run",
                str(tmp_path / "good.toml"),
                "--out",
                str(out_b),
                "--scheduler",
                f"tcp://127.0.0.1:{port}",
                "--json",
            ]
        )
        assert rc == 0
    finally:
        for p in (worker, sched):
            p.terminate()
        for p in (worker, sched):
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
    rows_b = _ok_rows(out_b)
    assert set(rows_b) == set(rows_a)
    for h, rb in rows_b.items():
        ra = rows_a[h]
        for m in ra["__metrics__"]:
            assert rb[m] == ra[m] or (rb[m] is None and ra[m] is None), (h, m)
        assert rb["worker"] != ra["worker"]  # really ran elsewhere
        ta, tb = pq.read_table(Store(out_a).trace_path(h)), pq.read_table(Store(out_b).trace_path(h))
        assert ta.equals(tb)


# -- report ---------------------------------------------------------------------------------------
def test_report_matches_compare(first, tmp_path):
    from necviz.commands.compare import METRICS, run
    from necviz.options import CompareOptions, SceneOptions
    from necviz.sweeps.report import report

    _, out, _ = first
    rep = report(out, folder=tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## tunnel_exit" in md and "| exit_s | controller | seeds | failed |" in md
    assert (tmp_path / "rep" / "cells.csv").read_text().count("\n") == 5  # header + 4 cells
    assert len((tmp_path / "rep" / "runs.csv").read_text().splitlines()) == 9
    assert rep["plots"] and all(Path(p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in rep["plots"])
    cmp_ = run(
        CompareOptions(
            SceneOptions("tunnel_exit", seed=0, duration_s=0.2, params={"exit_s": 0.1}), ("nec",), seeds=2, sift=False
        ),
        out=None,
    )["controllers"]["nec"]
    cell = next(
        c for c in rep["table"] if c["columns"]["controller"] == "nec" and c["columns"]["scenario_params.exit_s"] == 0.1
    )
    assert cell["seeds"] == [0, 1]
    compared = 0
    for m in METRICS:
        if m not in cell["stats"]:
            continue
        st = cell["stats"][m]
        if cmp_[m] is None:
            assert st["mean"] is None
            continue
        assert st["mean"] == pytest.approx(cmp_[m], rel=1e-12, abs=1e-12)
        assert st["ci95"] == pytest.approx(cmp_[m + "_ci95"], rel=1e-9, abs=1e-12)
        compared += 1
    assert compared >= 4
    # the table shows those means
    line = next(ln for ln in md.splitlines() if ln.startswith("| 0.1 | nec |"))
    assert f"| {int(cmp_['frames'])} |" in line


def test_report_refuses_to_replace_and_unknown_metrics(first, tmp_path, capsys):
    _, out, _ = first
    assert main(["sweep", "report", str(out), "--out", str(tmp_path / "r"), "--metrics", "frames"]) == 0
    capsys.readouterr()
    assert main(["sweep", "report", str(out), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--force" in err
    assert main(["sweep", "report", str(out), "--out", str(tmp_path / "r"), "--force", "--metrics", "nope"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'nope'" in err and "saturated_frames_50" in err


def test_show_reruns_a_cell_deterministically(first, tmp_path):
    from necviz.commands.sweep_show import show
    from necviz.options import ViewerOptions

    _, out, _ = first
    h = next(iter(_ok_rows(out)))
    res = show(out, h[:6], ViewerOptions(save=tmp_path / "run.rrd"), stream=None)
    assert res["hash"] == h and res["matches"]
    assert res["metrics"]["saturated_frames_50"] == res["row"]["saturated_frames_50"]
    assert (tmp_path / "run.rrd").stat().st_size > 10_000


# -- interruption and resume ----------------------------------------------------------------------
LAUNCH = (
    "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "from necviz.commands.cli import main; sys.exit(main(sys.argv[1:]))"
)


def test_ctrl_c_keeps_finished_rows_and_resume_adds_only_the_missing(client, tmp_path):
    f = _write(
        tmp_path / "ten.toml",
        'seeds = "0..9"\nduration_s = 0.2\ncontrollers = ["fixed"]\n'
        'scenarios = [{ name = "tunnel_exit", params = { exit_s = 0.1 } }]\n',
    )
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            LAUNCH,
            "sweep",
            "run",
            str(f),
            "--out",
            str(out),
            "--workers",
            "1",
            "--dashboard",
            "off",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    store = Store(out)
    deadline = time.monotonic() + 150
    while len(store.done()) < 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal sends: the whole process group
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "--resume" in err and "Traceback" not in err
    deadline = time.monotonic() + 20  # the workers end with it
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        pytest.fail("worker processes outlived the interrupted sweep")
    kept = {h: (store.row_path(h).stat().st_ino, store.row_path(h).stat().st_mtime_ns) for h in store.done()}
    assert 1 <= len(kept) < 10
    assert not (out / ".lock").exists()
    st = json.loads(_run_cli(["sweep", "status", str(out), "--json"]))
    assert (st["ok"], st["missing"]) == (len(kept), 10 - len(kept))

    res = run_sweep(load_plan(f), out, SweepOptions(resume=True), client=client, stream=None)
    assert (res.skipped, res.written) == (len(kept), 10 - len(kept))
    assert len(store.done()) == 10
    for h, ident in kept.items():
        s = store.row_path(h).stat()
        assert (s.st_ino, s.st_mtime_ns) == ident  # earlier rows untouched
    m = json.loads((out / "manifest.json").read_text())
    assert [s["interrupted"] for s in m["sessions"]] == [True, False]


def _run_cli(args) -> str:
    r = subprocess.run([sys.executable, "-m", "necviz", *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return r.stdout


def _kill_worker_running(client, run_hash: str, timeout_s: float = 60.0):
    """SIGKILL the worker process that is running ``run_hash`` (about a second into it); its pid."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        busy = [w for w, keys in client.processing().items() if any(run_hash in k for k in keys)]
        if busy:
            time.sleep(1.0)  # mid-run (or mid warm-up on a fresh worker)
            pid = client.run(os.getpid, workers=busy)[busy[0]]
            os.kill(pid, signal.SIGKILL)
            return pid
        time.sleep(0.05)
    return None


def test_a_killed_workers_run_is_retried(client, tmp_path):
    f = _write(
        tmp_path / "one.toml", 'seeds = "3"\nduration_s = 1.5\ncontrollers = ["fixed"]\nscenarios = ["tunnel_exit"]\n'
    )
    plan = load_plan(f)
    out = tmp_path / "out"
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("res", run_sweep(plan, out, client=client, stream=None)))
    t.start()
    killed = _kill_worker_running(client, plan.runs[0].hash)
    t.join(180)
    assert killed is not None and not t.is_alive()
    res = box["res"]
    assert (res.ok, res.failed) == (1, 0)
    row = Store(out).read_rows()[0]
    assert row["status"] == "ok" and not row["worker"].endswith(f":{killed}")


# -- files and folders ------------------------------------------------------------------------------
BAD = [
    ("seeds = '0..1'\nseed = 1\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "unknown key(s) seed"),
    ("controllers = ['nec']\nscenarios = ['flicker']\n", "'seeds'"),
    ("seeds = 3\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "seeds must be"),
    ("seeds = '5..1'\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "seeds:"),
    ("seeds = '0'\ncontrollers = ['nope']\nscenarios = ['flicker']\n", "controllers[0].name"),
    (
        "seeds = '0'\ncontrollers = [{ name = 'nec', params = { bogus = 1 } }]\nscenarios = ['flicker']\n",
        "controllers[0].params",
    ),
    (
        "seeds = '0'\ncontrollers = [{ name = 'nec', params = { goal = 'x' } }]\nscenarios = ['flicker']\n",
        "controllers[0].params",
    ),
    ("seeds = '0'\ncontrollers = ['nec']\nscenarios = ['nowhere']\n", "scenarios[0].name"),
    (
        "seeds = '0'\ncontrollers = ['nec']\n[[scenarios]]\nname = 'tunnel_exit'\nparams = { step_db = 1000 }\n",
        "scenarios[0].params.step_db",
    ),
    (
        "seeds = '0'\ncontrollers = ['nec']\n[[scenarios]]\nname = 'tunnel_exit'\nparams = { nope = [1, 2] }\n",
        "scenarios[0].params.nope",
    ),
    (
        "seeds = '0'\ncontrollers = ['nec']\n[[scenarios]]\nname = 'tunnel_exit'\nzip = { step_db = [60, 90], "
        "transition_ms = [15] }\n",
        "scenarios[0].zip",
    ),
    ("seeds = '0'\ncontrollers = ['nec']\nscenarios = ['flicker']\nsim = { 'dvs.nope' = 1 }\n", "dvs.nope"),
    ("seeds = '0'\nduration_s = -1\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "duration_s"),
    ("seeds = '0'\nsift = 'yes'\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "sift"),
    ("seeds = '0'\ncontrollers = ['nec']\nscenarios = [{ name = 'flicker', color = 1 }]\n", "scenarios[0]: unknown"),
    ("seeds = '0'\ncontrollers = ['nec']\nprofiles = ['missing.json']\nscenarios = ['flicker']\n", "missing.json"),
    ("seeds = [0\n", "invalid TOML"),
    ("seeds = '0..4294967295'\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "more than 10,000 seeds"),
    ("seeds = '0'\nduration_s = 1e12\ncontrollers = ['nec']\nscenarios = ['flicker']\n", "duration_s"),
]


@pytest.mark.parametrize("text,needle", BAD)
def test_bad_sweep_files_give_one_line_naming_the_key(tmp_path, capsys, text, needle):
    f = _write(tmp_path / "bad.toml", text)
    assert main(["sweep", "plan", str(f), "--no-estimate"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("necviz: error: ") and err.count("\n") == 1, err
    assert needle in err and str(f) in err


def test_a_million_run_sweep_is_refused_from_its_counts_at_once(tmp_path, capsys):
    """1,000,000 runs are counted, not built: refused in about the time it takes to start."""
    import resource

    goals = ", ".join(str(100 + k) for k in range(10))
    steps = ", ".join(str(60 + 5 * k) for k in range(10))
    f = _write(
        tmp_path / "big.toml",
        f'seeds = "0..999"\ncontrollers = [{{ name = "nec", params = {{ goal = [{goals}] }} }}]\n'
        f'[[scenarios]]\nname = "tunnel_exit"\nparams = {{ step_db = [{steps}], transition_ms = [{steps}] }}\n',
    )
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    assert main(["sweep", "plan", str(f), "--no-estimate"]) == 2
    took = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "1,000,000 runs" in err and "at most 100,000" in err, err
    assert took < 5 and resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 50_000  # kB


def test_plan_counts_estimate_and_checks_metrics(tmp_path, capsys):
    f = _write(tmp_path / "p.toml", SWEEP + "\n")
    assert main(["sweep", "plan", str(f), "--json", "--workers", "2"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert (d["runs"], d["cells"], d["seeds"], d["controller_configurations"]) == (8, 4, 2, 2)
    assert d["swept"] == {"scenario_params.exit_s": [0.1, 5.0]}
    assert d["simulated_s"] == pytest.approx(8 * 0.2)
    est = d["estimate"]
    assert est["workers"] == 2 and est["run_s_total"] > 0 and est["wall_s"] == pytest.approx(est["run_s_total"] / 2)
    assert "saturated_frames_50" in est["metrics"]
    g = _write(tmp_path / "m.toml", 'metrics = ["saturated_frames_50", "bogus"]\n' + GOOD)
    assert main(["sweep", "plan", str(g)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "metrics" in err and "'bogus'" in err


def test_output_folder_rules(first, tmp_path, capsys):
    plan, out, _ = first
    f = tmp_path / "tiny.toml"
    _write(f, SWEEP)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    cases = [
        (["--out", str(out)], "not empty"),
        (["--out", str(other), "--force"], "not a sweep folder"),
        (["--out", str(tmp_path / "new"), "--resume"], "no sweep to resume"),
        (["--out", str(other / "notes.txt")], "is a file"),
    ]
    for extra, needle in cases:
        assert main(["sweep", "run", str(f), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert (other / "notes.txt").read_text() == "mine"
    assert not (tmp_path / "new").exists()
    # resuming a finished sweep runs nothing; a changed grid is refused
    res = run_sweep(plan, out, SweepOptions(resume=True), stream=None)
    assert (res.skipped, res.written) == (8, 0)
    _write(f, SWEEP.replace('"0..1"', '"0"'))
    assert main(["sweep", "run", str(f), "--out", str(out), "--resume"]) == 2
    assert "not in" in capsys.readouterr().err


def test_damaged_rows_are_named_in_one_line_and_run_again_on_resume(first, client, tmp_path, capsys):
    import shutil

    plan, src, _ = first
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    store = Store(out)
    ok = sorted(_ok_rows(out))
    cut, empty = ok[0], ok[1]
    data = store.row_path(cut).read_bytes()
    store.row_path(cut).write_bytes(data[: len(data) // 2])  # a truncated copy
    store.row_path(empty).write_bytes(b"")  # a row emptied by a full disk
    st = json.loads(_run_cli(["sweep", "status", str(out), "--json"]))
    assert (st["ok"], st["missing"]) == (2, 2) and set(st["unreadable"]) == {cut, empty}
    assert main(["sweep", "status", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.count("unreadable") == 1 and "--resume" in text
    assert main(["sweep", "report", str(out), "--out", str(tmp_path / "rep")]) == 0
    warn = [ln for ln in capsys.readouterr().out.splitlines() if "unreadable" in ln]
    assert len(warn) == 1 and "2 result rows unreadable" in warn[0]
    assert main(["sweep", "show", str(out), "--run", empty, "--save", str(tmp_path / "s.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unreadable result row" in err and not (tmp_path / "s.rrd").exists()
    res = run_sweep(plan, out, SweepOptions(resume=True), client=client, stream=None)
    assert (res.skipped, res.written, res.ok) == (6, 2, 2)  # exactly the damaged two, run again
    assert set(_ok_rows(out)) == set(ok) and len(list((out / "runs").glob("*.damaged"))) == 2


def test_a_sweep_may_not_write_over_its_own_sweep_file(first, tmp_path, capsys):
    import shutil

    _, src, _ = first
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    before = (out / "sweep.toml").read_bytes()
    assert main(["sweep", "run", str(out / "sweep.toml"), "--out", str(out), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is the input file" in err
    assert (out / "sweep.toml").read_bytes() == before and (out / "manifest.json").exists()


def test_retry_failed_runs_only_the_failed_again(first, client):
    plan, out, _ = first
    before = {h: Store(out).row_path(h).stat().st_mtime_ns for h in Store(out).done()}
    res = run_sweep(plan, out, SweepOptions(resume=True, retry_failed=True), client=client, stream=None)
    assert (res.skipped, res.failed, res.ok) == (4, 4, 0)  # they fail again, for the same reason
    after = {h: Store(out).row_path(h).stat().st_mtime_ns for h in Store(out).done()}
    ok = set(_ok_rows(out))
    assert all(after[h] == before[h] for h in ok) and all(after[h] != before[h] for h in set(before) - ok)


def test_a_run_whose_worker_keeps_dying_is_recorded_failed(tmp_path):
    """With no retries allowed, one death of the worker running it makes it a failed row; the sweep goes on.

    Two workers, two runs: one each (a worker also holding a queued run would take that one down too)."""
    from necviz.sweeps.engine import connect

    f = _write(
        tmp_path / "two.toml",
        'seeds = "0..1"\nduration_s = 1.5\ncontrollers = ["fixed"]\nscenarios = ["tunnel_exit"]\n',
    )
    plan = load_plan(f)
    out = tmp_path / "out"
    with connect(workers=2, dashboard=None, retries=0) as c:
        box = {}
        t = threading.Thread(target=lambda: box.setdefault("res", run_sweep(plan, out, client=c, stream=None)))
        t.start()
        victim = plan.runs[0].hash
        killed = _kill_worker_running(c, victim)
        t.join(180)
    assert killed is not None and not t.is_alive()
    rows = {r["hash"]: r for r in Store(out).read_rows()}
    assert len(rows) == 2
    assert rows[victim]["status"] == "failed" and rows[victim]["error"].startswith("KilledWorker")
    assert rows[plan.runs[1].hash]["status"] == "ok"


def test_hash_is_canonical():
    spec = {
        "scenario": "tunnel_exit",
        "seed": 3,
        "duration_s": 2.0,
        "scenario_params": {"step_db": 90.0},
        "controllers": ["nec"],
        "controller_params": {"nec": {"goal": 110, "dead_band": 4}},
        "profile": None,
        "sim": {"dvs.c_on": 0.3},
        "sift": False,
    }
    h = spec_hash(spec)
    assert len(h) == 16 and all(c in "0123456789abcdef" for c in h)
    reordered = dict(reversed(list(spec.items())))
    reordered["controller_params"] = {"nec": {"dead_band": 4, "goal": 110.0}}
    reordered["scenario_params"] = {"step_db": 90}
    assert spec_hash(reordered) == h
    for key, value in (
        ("seed", 4),
        ("duration_s", 2.5),
        ("sim", {"dvs.c_on": 0.31}),
        ("sift", True),
        ("controller_params", {"nec": {"goal": 111}}),
    ):
        assert spec_hash({**spec, key: value}) != h, key


def test_hash_follows_a_scenario_files_content_not_its_place(tmp_path):
    a = _write(tmp_path / "s.toml", 'name = "tunnel_exit"\n[params]\nstep_db = 90\n')
    (tmp_path / "moved").mkdir()
    b = _write(tmp_path / "moved" / "s.toml", a.read_text())
    spec = {
        "scenario": str(a),
        "seed": 0,
        "duration_s": None,
        "scenario_params": {},
        "controllers": ["nec"],
        "controller_params": {},
        "profile": None,
        "sim": {},
        "sift": False,
    }
    assert spec_hash(spec) == spec_hash({**spec, "scenario": str(b)})
    _write(b, 'name = "tunnel_exit"\n[params]\nstep_db = 100\n')
    assert spec_hash(spec) != spec_hash({**spec, "scenario": str(b)})


def test_grid_zip_sim_none_and_duplicates(tmp_path):
    plan = load_plan(
        _write(
            tmp_path / "g.toml",
            """
seeds = "0..2"
controllers = ["fixed", { name = "nec", params = { goal = [100, 120] } }, "fixed"]
sim = { "dvs.c_on" = 0.3 }
[[scenarios]]
name = "tunnel_exit"
params = { transition_ms = [15, 40, 150] }
zip = { step_db = [60, 90], inside_log = [1.0, 2.0] }
sim = { "dvs.max_event_rate" = [12e6, "none"] }
""",
        )
    )
    # 3 transitions × 2 zipped × 2 rate ceilings = 12 scenario configurations; 3 controller configurations
    # (the second "fixed" is the same runs again) × 3 seeds
    assert len(plan.runs) == 12 * 3 * 3 and plan.duplicates == 12 * 3
    specs = [r.spec for r in plan.runs]
    assert {(s["scenario_params"]["step_db"], s["scenario_params"]["inside_log"]) for s in specs} == {
        (60, 1.0),
        (90, 2.0),
    }
    assert {s["sim"]["dvs.max_event_rate"] for s in specs} == {12e6, None}
    assert all(s["sim"]["dvs.c_on"] == 0.3 for s in specs)
    assert {json.dumps(s["controller_params"], sort_keys=True) for s in specs} == {
        "{}",
        '{"nec": {"goal": 100}}',
        '{"nec": {"goal": 120}}',
    }
    assert len(set(plan.hashes)) == len(plan.runs)
    assert plan.cells() == len(plan.runs) // 3
    assert not math.isnan(plan.runs[0].columns["scenario_params.transition_ms"])
