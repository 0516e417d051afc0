"""``--serve`` listens on 127.0.0.1 only (web page and data port) unless ``--bind`` says otherwise."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import psutil
import pytest
from viewer_check import free_port

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


def listening(proc: psutil.Process) -> set[tuple[str, int]]:
    pids = {proc.pid, *(c.pid for c in proc.children(recursive=True))}
    return {
        (c.laddr.ip, c.laddr.port)
        for c in psutil.net_connections(kind="inet")
        if c.status == psutil.CONN_LISTEN and c.pid in pids
    }


def serve(tmp_path, *extra) -> tuple[subprocess.Popen, set, str]:
    grpc, web = free_port(), free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "necviz",
            "demo",
            "--duration",
            "0.2",
            "--controllers",
            "nec",
            "--serve",
            "--grpc-port",
            str(grpc),
            "--web-port",
            str(web),
            "--no-prompt",
            *extra,
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        # Ctrl-C must reach it even when the suite itself runs in the background (a shell's
        # `cmd &` ignores SIGINT, and children inherit that, so Python would not catch it)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    lines = []
    deadline = time.time() + 120
    while time.time() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if "still serving" in line:
            break
    text = "".join(lines)
    assert "still serving" in text, text
    parent = psutil.Process(proc.pid)
    socks = listening(parent)
    servers = parent.children(recursive=True)
    proc.send_signal(signal.SIGINT)
    proc.wait(30)
    gone, alive = psutil.wait_procs(servers, timeout=10)
    assert not alive, f"the web viewer server outlived necviz: {alive}"
    assert {grpc, web} <= {port for _, port in socks}, (socks, grpc, web)
    return proc, socks, text


def test_serve_listens_on_loopback_only(tmp_path):
    proc, socks, text = serve(tmp_path)
    assert socks and all(ip in ("127.0.0.1", "::1") for ip, _ in socks), socks
    assert "http://127.0.0.1:" in text and "warning" not in text
    assert proc.returncode == 0


@pytest.mark.skipif(sys.platform != "linux", reason="reads the listening sockets of the process tree")
def test_bind_exposes_it_on_purpose_and_warns(tmp_path):
    _, socks, text = serve(tmp_path, "--bind", "0.0.0.0")
    assert any(ip == "0.0.0.0" for ip, _ in socks), socks
    assert "warning: serving on 0.0.0.0" in text


def _demo_serve(grpc, web):
    argv = [sys.executable, "-m", "necviz", "demo", "--duration", "0.2", "--controllers", "nec", "--serve"]
    argv += ["--grpc-port", str(grpc), "--web-port", str(web), "--no-prompt"]
    return argv


def test_a_busy_port_is_refused_at_once_naming_its_holder(tmp_path):
    """A port someone holds (here: this test) is one line before anything starts, not a 48 s stall
    followed by data sent to whoever listens there."""
    import os
    import socket

    grpc, web = free_port(), free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", grpc))
        s.listen()
        t0 = time.monotonic()
        proc = subprocess.run(_demo_serve(grpc, web), cwd=tmp_path, capture_output=True, text=True, timeout=120)
        took = time.monotonic() - t0
    err = proc.stderr.strip()
    assert proc.returncode == 2 and "\n" not in err, err
    assert f"port {grpc} on 127.0.0.1 is already in use by process {os.getpid()}" in err
    assert took < 30 and "demo:" not in proc.stdout  # refused before the run started


@pytest.mark.skipif(sys.platform != "linux", reason="the kernel's parent-death signal is Linux's")
def test_the_web_server_dies_with_a_killed_necviz(tmp_path):
    """SIGKILL leaves necviz no chance to stop its server: the server must go by itself, and its
    ports must be free for the next run."""
    grpc, web = free_port(), free_port()
    proc = subprocess.Popen(
        [*_demo_serve(grpc, web)],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline:
        line = proc.stdout.readline()
        if not line or "still serving" in line:
            break
    servers = psutil.Process(proc.pid).children(recursive=True)
    assert servers and {grpc, web} <= {port for _, port in listening(psutil.Process(proc.pid))}
    proc.kill()
    proc.wait(30)
    gone, alive = psutil.wait_procs(servers, timeout=15)
    assert not alive, f"the web viewer server outlived a killed necviz: {alive}"
    from necviz.dashboard.viewer import _listener

    assert _listener("127.0.0.1", grpc) is None and _listener("127.0.0.1", web) is None
