"""Headless looks at a recording: the native Rerun viewer and the web viewer in headless Chromium.

Not a test module; ``tests/test_viewer.py`` uses it, and it runs on its own for a quick look::

    python tests/viewer_check.py native out.rrd shot.png [--frame N]
    python tests/viewer_check.py browser out.rrd shot.png

Both functions return a dict of evidence (JSON-serialisable). They raise
:class:`ViewerUnavailable` when this machine cannot run the viewer at all (no ``rerun`` command,
no Vulkan driver, no Chromium: a test should skip) and :class:`ViewerCheckError` when the viewer
ran but did not load the recording (a test should fail).

* :func:`native_screenshot` drives ``rerun --headless`` through ``rerun.experimental.ViewerClient``
  on Mesa's software Vulkan driver (``lavapipe``, Debian ``mesa-vulkan-drivers``; ``WGPU_BACKEND=vulkan``,
  the OpenGL path panics). The viewer reports its views and any per-view errors. Its gRPC port binds
  0.0.0.0 (``ViewerClient.spawn`` has no bind option) for the few seconds the check runs.
* :func:`browser_screenshot` serves the file with ``rerun --serve-web FILE --bind 127.0.0.1`` (gRPC and
  the web viewer on free localhost ports) and loads the page in headless Chromium (Debian ``chromium``),
  driven over the DevTools protocol on ``--remote-debugging-pipe`` with the standard library only.
  Without a GPU Chromium renders WebGL with SwiftShader. Evidence that the page shows the recording
  and not the "Loading Application Bundle" screen: the app's JS handle exists and has not panicked,
  the canvas is shown and the loading text hidden; the viewer's own state (``WebHandle.viewer_state()``,
  a protobuf decoded here) names the recording's id and the blueprint's views; the screenshot is
  stable and far from uniform.
"""

from __future__ import annotations

import base64
import fcntl
import glob
import hashlib
import json
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np

#: Browsers tried in order (``NECVIZ_CHROMIUM`` overrides).
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

#: A screenshot of the viewer with data has thousands of colours (image, anti-aliased plots and text);
#: the loading screen is one background colour, a header bar and at most a line of text. Measured at
#: 1600x900: loaded viewer (light theme) 1650 colours, 88 % one colour; screen before the app paints
#: 2 colours, 95 % one colour.
MIN_DISTINCT_COLOURS = 500
MAX_DOMINANT_FRACTION = 0.93


class ViewerUnavailable(RuntimeError):
    """This machine cannot run the viewer (missing program or driver): skip, don't fail."""


class ViewerCheckError(AssertionError):
    """The viewer ran but did not show the recording."""


# ---------------------------------------------------------------- shared helpers


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now (the usual small race with whoever binds next)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rerun_executable() -> str:
    """The ``rerun`` command that ships with the wheel: next to this interpreter first, then PATH."""
    here = Path(sys.executable).parent / "rerun"
    if here.exists():
        return str(here)
    found = shutil.which("rerun")
    if not found:
        raise ViewerUnavailable("no `rerun` command (it ships with rerun-sdk, in the venv's bin/)")
    return found


def vulkan_icds() -> list[str]:
    """Vulkan driver manifests the loader will see (lavapipe is ``lvp_icd.*.json``)."""
    env = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if env:
        return [p for p in env.split(os.pathsep) if os.path.exists(p)]
    found: list[str] = []
    for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d"):
        found += sorted(glob.glob(os.path.join(d, "*.json")))
    return found


def find_chromium() -> str | None:
    exe = os.environ.get("NECVIZ_CHROMIUM")
    if exe:
        return exe if os.access(exe, os.X_OK) else None
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


def recording_ids(rrd_path: str | Path) -> dict:
    """Application and recording id of the file's recording, and whether it carries a blueprint."""
    from rerun.chunk import RrdReader

    r = RrdReader(str(rrd_path))
    recs = r.recordings()
    if not recs:
        raise ViewerCheckError(f"{rrd_path}: no recording store in the file")
    return {
        "application_id": recs[0].application_id,
        "recording_id": recs[0].recording_id,
        "has_blueprint": bool(r.blueprints()),
    }


def image_stats(png: bytes) -> dict:
    """Objective numbers separating a drawn viewer from a uniform (loading / blank) screen."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ViewerCheckError("screenshot is not a decodable PNG")
    flat = img.reshape(-1, 3)
    packed = (flat[:, 0].astype(np.uint32) << 16) | (flat[:, 1].astype(np.uint32) << 8) | flat[:, 2]
    values, counts = np.unique(packed, return_counts=True)
    grey = flat[(flat[:, 0] == flat[:, 1]) & (flat[:, 1] == flat[:, 2])][:, 0]
    return {
        "width": int(img.shape[1]),
        "height": int(img.shape[0]),
        "distinct_colours": int(values.size),
        "dominant_fraction": round(float(counts.max() / packed.size), 4),
        "std": round(float(img.std()), 2),
        "grey_levels": int(np.unique(grey).size),
    }


def looks_drawn(stats: dict) -> bool:
    return stats["distinct_colours"] >= MIN_DISTINCT_COLOURS and stats["dominant_fraction"] <= MAX_DOMINANT_FRACTION


def _view_dict(v) -> dict:
    return {
        "view_id": str(v.view_id),
        "name": v.name,
        "class": v.view_class,
        "origin": v.origin,
        "visible": bool(v.visible),
        "reports": [str(r) for r in (getattr(v, "reports", None) or [])],
    }


# ---------------------------------------------------------------- native viewer


def native_screenshot(
    rrd_path, png_path, frame: int | None = None, timeout_s: float = 60, timeline: str = "frame", max_size: int = 1600
) -> dict:
    """Open ``rrd_path`` in a headless native viewer, screenshot it to ``png_path``, return evidence.

    Evidence: ``loading_finished``, ``active_recording``, ``views`` (name, class, origin, ``reports``: the
    per-view errors the viewer shows), ``view_errors`` (views with reports), ``image`` (stats of the whole
    screenshot), ``view_images`` (stats per 2D view), ``adapter`` (the wgpu adapter line), ``warnings``.
    Raises :class:`ViewerUnavailable` without a Vulkan driver, :class:`ViewerCheckError` if the file does
    not finish loading in ``timeout_s``. Per-view errors are returned, not raised: assert on them.
    """
    from rerun.experimental import ViewerClient

    rrd_path = Path(rrd_path).resolve()
    if not rrd_path.exists():
        raise FileNotFoundError(rrd_path)
    exe = rerun_executable()
    icds = vulkan_icds()
    if not icds:
        raise ViewerUnavailable(
            "no Vulkan driver for the headless native viewer "
            "(apt-get install mesa-vulkan-drivers gives the lavapipe CPU driver)"
        )
    t0 = time.monotonic()
    deadline = t0 + timeout_s
    ev: dict = {"rrd": str(rrd_path), "png": str(png_path), "vulkan_icds": icds, "frame": frame}
    # spawn() has no env argument: the child inherits ours, so set the backend just around it.
    old = os.environ.get("WGPU_BACKEND")
    os.environ["WGPU_BACKEND"] = "vulkan"
    try:
        viewer = ViewerClient.spawn(
            headless=True,
            port=free_port(),
            hide_welcome_screen=True,
            memory_limit="1GB",
            server_memory_limit="256MiB",
            executable_path=exe,
        )
    except ConnectionError as e:  # the viewer panicked at start: typically no usable Vulkan adapter
        raise ViewerUnavailable(
            f"headless native viewer did not start ({e}; its stderr says why, usually "
            f"'No graphics adapter was found'); Vulkan drivers seen: {icds}"
        ) from e
    finally:
        if old is None:
            os.environ.pop("WGPU_BACKEND", None)
        else:
            os.environ["WGPU_BACKEND"] = old
    try:
        with viewer as v:
            try:
                v.open(str(rrd_path))
            except ConnectionError as e:  # the viewer died at start: rendering context failed
                raise ViewerUnavailable(
                    f"headless native viewer did not start ({e}); Vulkan drivers seen: {icds}"
                ) from e
            st = v.get_state()
            while (st.loading or not st.active_recording) and time.monotonic() < deadline:
                time.sleep(0.2)
                st = v.get_state()
            ev["loading_finished"] = not st.loading and bool(st.active_recording)
            ev["load_s"] = round(time.monotonic() - t0, 2)
            if not ev["loading_finished"]:
                raise ViewerCheckError(
                    f"native viewer: {rrd_path.name} still loading after {timeout_s} s "
                    f"(loading={st.loading}, active={st.active_recording!r})"
                )
            if frame is not None:
                v.set_time(timeline, sequence=int(frame), play_state="paused")
            # The first paint after loading can come before the views have their data: shoot until
            # two consecutive screenshots are identical.
            png, prev, digest, shots = b"", None, None, 0
            while time.monotonic() < deadline:
                png = v.take_screenshot(max_size=max_size)
                shots += 1
                digest = hashlib.sha1(png).hexdigest()
                if digest == prev:
                    break
                prev = digest
                time.sleep(0.3)
            ev["screenshots_until_stable"] = shots
            ev["stable"] = digest == prev and shots > 1
            if not png:
                raise ViewerCheckError(f"native viewer: no screenshot within {timeout_s} s")
            Path(png_path).write_bytes(png)
            ev["image"] = image_stats(png)
            st = v.get_state()
            rec = next((r for r in st.recordings if r.store_id == st.active_recording), None)
            ev["active_recording"] = st.active_recording
            if rec is not None:
                ev["current_timeline"], ev["current_time"] = rec.current_timeline, rec.current_time
                ev["timelines"] = {t.name: [t.start, t.end] for t in rec.timelines}
            ev["views"] = [_view_dict(x) for x in st.views]
            ev["view_errors"] = {x["name"]: x["reports"] for x in ev["views"] if x["reports"]}
            ev["view_images"] = {}
            for x in ev["views"]:
                if x["class"] in ("2D", "Spatial2D") and x["visible"]:
                    ev["view_images"][x["name"]] = image_stats(v.take_screenshot(x["view_id"], max_size=800))
            logs = v.get_logs()
            ev["adapter"] = next((m.message for m in logs if "adapter backend" in m.message), None)
            ev["warnings"] = [f"{m.level} {m.target}: {m.message}" for m in logs if m.level in ("WARN", "ERROR")]
    except ConnectionError as e:
        raise ViewerCheckError(f"native viewer connection lost: {e}") from e
    ev["elapsed_s"] = round(time.monotonic() - t0, 2)
    return ev


# ---------------------------------------------------------------- DevTools protocol over a pipe


class _CdpPipe:
    """Minimal Chrome DevTools protocol client on ``--remote-debugging-pipe`` (fd 3 in, fd 4 out;
    messages are JSON terminated by a NUL byte). Events are kept only if ``keep_event(msg)`` says so."""

    def __init__(self, exe: str, args: list[str], log_path: str):
        to_r, to_w = os.pipe()  # we write, Chromium reads on fd 3
        from_r, from_w = os.pipe()  # Chromium writes on fd 4, we read
        # copies numbered >= 10 so the dup2 onto 3 and 4 cannot clobber one another
        hi_in = fcntl.fcntl(to_r, fcntl.F_DUPFD_CLOEXEC, 10)
        hi_out = fcntl.fcntl(from_w, fcntl.F_DUPFD_CLOEXEC, 10)

        def _child_fds():  # runs in the child between fork and exec; dup2 clears close-on-exec
            os.dup2(hi_in, 3)
            os.dup2(hi_out, 4)

        self._log = open(log_path, "wb")
        try:
            # close_fds=False: fds 3 and 4 must survive; every other Python fd is close-on-exec anyway
            self.proc = subprocess.Popen(
                [exe, "--remote-debugging-pipe", *args],
                stdin=subprocess.DEVNULL,
                stdout=self._log,
                stderr=subprocess.STDOUT,
                close_fds=False,
                preexec_fn=_child_fds,
                start_new_session=True,
            )
        finally:
            for fd in (to_r, from_w, hi_in, hi_out):
                os.close(fd)
        self._w, self._r = to_w, from_r
        self._buf = b""
        self._id = 0
        self.keep_event = lambda msg: False  # events are dropped unless this says keep
        self.events: list[dict] = []

    def _message(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no answer from Chromium over the DevTools pipe")
            ready, _, _ = select.select([self._r], [], [], left)
            if ready:
                chunk = os.read(self._r, 1 << 20)
                if not chunk:
                    raise ViewerCheckError(f"Chromium closed the DevTools pipe (exit code {self.proc.poll()})")
                self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def call(
        self, method: str, params: dict | None = None, session: str | None = None, timeout_s: float = 30.0
    ) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        data = json.dumps(msg).encode() + b"\0"
        while data:
            data = data[os.write(self._w, data) :]
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._message(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise ViewerCheckError(f"DevTools {method}: {reply['error']}")
                return reply.get("result", {})
            if "method" in reply and self.keep_event(reply):
                self.events.append(reply)

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                try:
                    self.call("Browser.close", timeout_s=5)
                    self.proc.wait(10)
                except Exception:  # noqa: BLE001 -- fall through to the signals below
                    pass
            _stop_group(self.proc)  # our own session: whatever of Chromium is left
        finally:
            for fd in (self._w, self._r):
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._log.close()


def _evaluate(cdp: _CdpPipe, session: str, expression: str, timeout_s: float = 30.0):
    r = cdp.call(
        "Runtime.evaluate",
        {"expression": expression, "returnByValue": True, "awaitPromise": True},
        session=session,
        timeout_s=timeout_s,
    )
    if "exceptionDetails" in r:
        raise ViewerCheckError(
            f"page script failed: {r['exceptionDetails'].get('text')} "
            f"{r['exceptionDetails'].get('exception', {}).get('description', '')}"
        )
    return r.get("result", {}).get("value")


# ---------------------------------------------------------------- the viewer's state, protobuf-encoded


def _pb_fields(buf: bytes):
    """(field number, wire type, value) of one protobuf message; LEN values stay bytes."""
    i, n = 0, len(buf)

    def varint():
        nonlocal i
        shift = out = 0
        while True:
            b = buf[i]
            i += 1
            out |= (b & 0x7F) << shift
            shift += 7
            if b < 0x80:
                return out

    while i < n:
        key = varint()
        field, wire = key >> 3, key & 7
        if wire == 0:
            yield field, wire, varint()
        elif wire == 1:
            yield field, wire, buf[i : i + 8]
            i += 8
        elif wire == 2:
            ln = varint()
            yield field, wire, buf[i : i + ln]
            i += ln
        elif wire == 5:
            yield field, wire, buf[i : i + 4]
            i += 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")


def decode_viewer_state(buf: bytes) -> dict:
    """The parts of the viewer-control ``GetStateResponse`` a check needs.

    Field numbers as the 0.41 web viewer encodes them (checked against the native viewer's JSON for the
    same file): 1 location, 2 active recording, 5 views (1 id, 2 class, 3 name, 4 origin, 5 visible),
    6 viewer version. Other view fields (e.g. reports) are kept as raw text under ``other``.
    """
    out: dict = {"location": None, "active_recording": None, "views": [], "viewer_version": None}
    for field, wire, val in _pb_fields(buf):
        if wire != 2:
            continue
        if field == 1:
            out["location"] = val.decode("utf-8", "replace")
        elif field == 2:
            out["active_recording"] = val.decode("utf-8", "replace")
        elif field == 6:
            out["viewer_version"] = val.decode("utf-8", "replace")
        elif field == 5:
            view: dict = {"other": []}
            for f, w, x in _pb_fields(val):
                key = {1: "view_id", 2: "class", 3: "name", 4: "origin"}.get(f)
                if key and w == 2:
                    view[key] = x.decode("utf-8", "replace")
                elif f == 5 and w == 0:
                    view["visible"] = bool(x)
                else:
                    view["other"].append(x.decode("utf-8", "replace") if isinstance(x, bytes) else x)
            out["views"].append(view)
    return out


# ---------------------------------------------------------------- web viewer in headless Chromium

_PAGE_STATE_JS = """(() => {
  const c = document.getElementById('the_canvas_id'), t = document.getElementById('center_text');
  const h = window._handle;
  let state = null, panic = null;
  if (h) { try { panic = h.has_panicked() ? String(h.panic_message()) : null; } catch (e) { panic = 'check failed: ' + e; }
           if (!panic) { try { state = Array.from(h.viewer_state()); } catch (e) { state = null; } } }
  return JSON.stringify({title: document.title, app_started: !!h, panic: panic,
    canvas_class: c ? c.className : null, center_class: t ? t.className : null,
    center_text: t ? t.innerText.trim() : null, state: state});
})()"""

_RENDERER_JS = """(() => {
  const gl = document.createElement('canvas').getContext('webgl2') || document.createElement('canvas').getContext('webgl');
  let r = null;
  if (gl) { const d = gl.getExtension('WEBGL_debug_renderer_info');
            r = d ? gl.getParameter(d.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER); }
  return JSON.stringify({webgl_renderer: r, webgpu_api: !!navigator.gpu});
})()"""


def _wait_http(url: str, proc: subprocess.Popen, deadline: float) -> None:
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ViewerCheckError(f"`rerun --serve-web` exited with code {proc.returncode}")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            pass
        time.sleep(0.2)
    raise ViewerCheckError(f"web viewer did not answer at {url}")


def browser_screenshot(
    rrd_path,
    png_path,
    timeout_s: float = 120,
    width: int = 1600,
    height: int = 900,
    expected_views: list[str] | None = None,
    theme: str | None = None,
    console: bool = False,
) -> dict:
    """Serve ``rrd_path`` to the web viewer on localhost, screenshot it in headless Chromium, return evidence.

    Passes only if the page shows the recording, not the loading screen: the app started and did not
    panic, the canvas is visible and the loading text hidden, the viewer's state names the file's
    recording id and at least one view (all of ``expected_views`` if given), and the screenshot is stable
    and drawn (:func:`looks_drawn`). Otherwise raises :class:`ViewerCheckError` with what was seen.
    Raises :class:`ViewerUnavailable` if no Chromium is installed.

    ``console=True`` also collects the page's console (warnings, errors, the wgpu adapter line); it
    costs time, since the viewer prints thousands of debug lines while compiling shaders.
    ``theme`` ("dark" / "light") overrides the browser's preference (headless Chromium: light).
    """
    rrd_path = Path(rrd_path).resolve()
    if not rrd_path.exists():
        raise FileNotFoundError(rrd_path)
    chromium = find_chromium()
    if not chromium:
        raise ViewerUnavailable("no Chromium found (apt-get install chromium, or set NECVIZ_CHROMIUM)")
    ids = recording_ids(rrd_path)
    t0 = time.monotonic()
    deadline = t0 + timeout_s
    grpc_port, web_port = free_port(), free_port()
    while web_port == grpc_port:
        web_port = free_port()
    grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    page_url = f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(grpc_url, safe='')}"
    if theme:
        page_url += f"&theme={theme}"
    ev: dict = {"rrd": str(rrd_path), "png": str(png_path), "chromium": chromium, "url": page_url, **ids}
    work = Path(tempfile.mkdtemp(prefix="necviz-browser-"))
    server = subprocess.Popen(
        [
            rerun_executable(),
            "--serve-web",
            str(rrd_path),
            "--bind",
            "127.0.0.1",
            "--port",
            str(grpc_port),
            "--web-viewer-port",
            str(web_port),
            "--server-memory-limit",
            "256MiB",
        ],
        stdin=subprocess.DEVNULL,
        stdout=open(work / "rerun-serve.log", "wb"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    cdp = None
    try:
        _wait_http(f"http://127.0.0.1:{web_port}/", server, min(deadline, time.monotonic() + 30))
        ev["served_s"] = round(time.monotonic() - t0, 2)
        cdp = _CdpPipe(
            chromium,
            [
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                f"--user-data-dir={work / 'profile'}",
                f"--window-size={width},{height}",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-dev-shm-usage",
                "--disable-extensions",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--hide-scrollbars",
                "--mute-audio",
                "about:blank",
            ],
            str(work / "chromium.log"),
        )
        ev["browser"] = cdp.call("Browser.getVersion").get("product")
        target = cdp.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = cdp.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        cdp.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            session=session,
        )
        # the viewer's console, minus its flood of debug lines (shader compilation)
        if console:
            cdp.keep_event = lambda m: (
                m["method"] == "Runtime.exceptionThrown"
                or (m["method"] == "Runtime.consoleAPICalled" and m["params"].get("type") != "debug")
            )
            cdp.call("Runtime.enable", session=session)
        cdp.call("Page.navigate", {"url": page_url}, session=session)

        # 1. the app started (wasm compiled, WebHandle running) and the viewer's state lists the views
        page: dict = {}
        state: dict = {}
        while time.monotonic() < deadline:
            page = json.loads(_evaluate(cdp, session, _PAGE_STATE_JS) or "{}")
            if page.get("panic"):
                raise ViewerCheckError(f"web viewer panicked: {page['panic']}")
            if page.get("state"):
                state = decode_viewer_state(bytes(page["state"]))
                if state["active_recording"] and state["views"]:
                    break
            time.sleep(1.0)
        ev["app_started_s"] = round(time.monotonic() - t0, 2)
        ev["page"] = {k: v for k, v in page.items() if k != "state"}
        ev["state"] = state
        ev["renderer"] = json.loads(_evaluate(cdp, session, _RENDERER_JS) or "{}")
        if not page.get("app_started"):
            raise ViewerCheckError(f"web viewer never started within {timeout_s} s; page: {ev['page']}")

        # 2. screenshots until two in a row are identical: software rendering first returns frames with
        #    the image views still loading (animated dots), or half drawn
        png, prev, shots, diffs = b"", None, 0, []
        stable = False
        while time.monotonic() < deadline:
            shot = cdp.call(
                "Page.captureScreenshot",
                {"format": "png"},
                session=session,
                timeout_s=max(5.0, deadline - time.monotonic()),
            )
            png = base64.b64decode(shot["data"])
            shots += 1
            ev.setdefault("shot_times_s", []).append(round(time.monotonic() - t0, 2))
            cur = _pixels(png)
            if prev is not None and cur.shape == prev.shape:
                diffs.append(round(float(np.abs(cur.astype(np.int16) - prev).mean()), 3))
                if diffs[-1] == 0:
                    stable = True
                    break
            prev = cur
            time.sleep(1.0)
        if not png:
            raise ViewerCheckError(f"web viewer: no screenshot within {timeout_s} s; page: {ev['page']}")
        Path(png_path).write_bytes(png)
        ev["screenshots_until_stable"] = shots
        ev["screenshot_mean_abs_diffs"] = diffs
        ev["stable"] = stable
        ev["image"] = image_stats(png)
        page = json.loads(_evaluate(cdp, session, _PAGE_STATE_JS) or "{}")
        ev["page"] = {k: v for k, v in page.items() if k != "state"}
        if page.get("state"):
            ev["state"] = state = decode_viewer_state(bytes(page["state"]))
        ev["elapsed_s"] = round(time.monotonic() - t0, 2)
    except (ViewerCheckError, TimeoutError) as e:
        raise ViewerCheckError(f"{e}\nlogs (rerun-serve.log, chromium.log): {work}") from e
    finally:
        if cdp is not None:
            if console:
                lines = _console_lines(cdp.events)
                ev["adapter"] = next((c for c in lines if "adapter backend" in c), None)
                ev["console"] = [c[:300] for c in lines[:40]]
            cdp.close()
        _stop_group(server)

    problems = _browser_problems(ev, expected_views)
    ev["loaded_recording"] = not problems
    if not problems:
        shutil.rmtree(work, ignore_errors=True)
    else:
        ev["logs"] = str(work)  # rerun-serve.log, chromium.log and the browser profile, kept for a look
        raise ViewerCheckError(
            "web viewer did not show the recording: "
            + "; ".join(problems)
            + f"\nevidence: {json.dumps(ev, default=str)[:4000]}"
        )
    return ev


def _stop_group(proc: subprocess.Popen) -> None:
    """Stop a process started with ``start_new_session=True`` and everything in its process group.

    The venv's ``rerun`` is a Python launcher that runs the real binary as a child: terminating only the
    launcher leaves the server running (and spinning), so signal the whole group."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            continue
        try:  # the launcher is gone; make sure its children went with it
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.5)


def _pixels(png: bytes) -> np.ndarray:
    import cv2

    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def _console_lines(events: list[dict]) -> list[str]:
    out = []
    for e in events:
        p = e["params"]
        if e["method"] == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append(f"exception: {d.get('text')} {d.get('exception', {}).get('description', '')}".strip())
            continue
        text = " ".join(str(a.get("value", a.get("description", a.get("type")))) for a in p.get("args", []))
        out.append(f"{p.get('type')}: {text.strip()}")
    return out


def _browser_problems(ev: dict, expected_views: list[str] | None) -> list[str]:
    page, state, image = ev.get("page", {}), ev.get("state", {}), ev.get("image", {})
    problems = []
    if not page.get("app_started"):
        problems.append("app never started (window._handle missing)")
    if page.get("panic"):
        problems.append(f"panic: {page['panic']}")
    if "visible" not in (page.get("canvas_class") or ""):
        problems.append(f"canvas not shown (class {page.get('canvas_class')!r})")
    if "Loading" in (page.get("center_text") or "") or "visible" in (page.get("center_class") or ""):
        problems.append(f"loading text still shown: {page.get('center_text')!r}")
    active = state.get("active_recording") or ""
    if ev["recording_id"] not in active:
        problems.append(f"active recording {active!r} is not the file's {ev['recording_id']!r}")
    names = [v.get("name") for v in state.get("views", [])]
    if not names:
        problems.append("the viewer reports no views")
    missing = [n for n in (expected_views or []) if n not in names]
    if missing:
        problems.append(f"views missing: {missing} (have {names})")
    if not ev.get("stable"):
        problems.append("screenshot never stable")
    if not image or not looks_drawn(image):
        problems.append(f"screenshot looks uniform (loading screen?): {image}")
    return problems


# ---------------------------------------------------------------- command line


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("how", choices=("native", "browser"))
    ap.add_argument("rrd")
    ap.add_argument("png")
    ap.add_argument("--frame", type=int, default=None)
    ap.add_argument("--timeout", type=float, default=None)
    a = ap.parse_args(argv)
    try:
        if a.how == "native":
            ev = native_screenshot(a.rrd, a.png, frame=a.frame, timeout_s=a.timeout or 60)
        else:
            ev = browser_screenshot(a.rrd, a.png, timeout_s=a.timeout or 120)
    except ViewerUnavailable as e:
        print(f"unavailable: {e}", file=sys.stderr)
        return 77
    print(json.dumps(ev, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
