"""Live tuning: change parameters while ``demo`` or ``live`` runs, without restarting.

Two ways in, same language:

* a prompt on the terminal (:class:`TuningConsole`): the input line stays apart from the live
  status line (shown below it), with history (up/down) and completion (Tab) of keys, lane and
  controller names — built on ``prompt_toolkit``; without a terminal, lines are read as they come;
* a watched file (``--tune-file FILE``, :class:`TuningFile`): whenever it is saved, every
  ``key = value`` line that changed is applied.

Language (``help`` prints it with every key's unit and meaning)::

    [LANE.]KEY = VALUE      e.g.  goal = 100      nec.dead_band = 0.05
    dvs.KEY = VALUE         the camera's DVS biases, e.g. dvs.c_on = 0.2, dvs.refractory_us = 50
    bias.NAME = C/F         a raw coarse/fine bias, e.g. bias.DiffBn = 4/39
    set [LANE.]KEY VALUE
    drive NAME [LANE]       switch the controller that drives the lane's camera
    mark [TEXT]             keep a clip around this moment (with --clips; always noted in the recording)
    status                  current settings
    help

Keys are what the lanes declare: every controller's tunable parameters
(:meth:`~necviz.core.control.Controller.tunables`: the camera limits ``exposure_min``,
``exposure_max``, ``gain_max`` and its own, e.g. NEC's ``dead_band``, ``full_band``, ``goal``)
and the P-TEDI thresholds ``c_on``, ``c_off`` and ``c`` (both). Without ``LANE.`` a key applies to
every lane that has it. Changes run on the streaming thread between two packets
(:meth:`~necviz.pipeline.Pipeline.tune`, :meth:`~necviz.pipeline.Pipeline.drive`), are logged to
the recording (``tuning``) and to the native recording, and bad values are refused with a reason.
``dvs.KEY`` and ``bias.NAME`` set the camera's DVS biases, P-TEDI's thresholds following
(:mod:`necviz.dvs_controls`, :meth:`~necviz.pipeline.Pipeline.tune_dvs`).
"""

from __future__ import annotations

import os
import re
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from necviz.core.control import CONTROLLERS
from necviz.core.errors import NecvizError, ParameterError
from necviz.dvs_controls import PREFIXES as DVS_PREFIXES
from necviz.pipeline import THRESHOLD_KEYS

SYNTAX = "[LANE.]KEY = VALUE | dvs.KEY = VALUE | bias.NAME = C/F | set [LANE.]KEY VALUE | drive NAME [LANE] | mark [TEXT] | status | help"

_ASSIGN = re.compile(r"^(?:set\s+)?(?:(?P<lane>[A-Za-z_][\w-]*)\.)?(?P<key>[A-Za-z_]\w*)\s*(?:=|\s)\s*(?P<value>\S+)$")
_DRIVE = re.compile(r"^drive\s+(?P<name>[\w-]+)(?:\s+(?P<lane>[\w-]+))?$")


@dataclass(frozen=True)
class Command:
    """One parsed line: ``kind`` is ``set``, ``dvs``, ``drive``, ``mark``, ``status`` or ``help``."""

    kind: str
    key: str | None = None
    value: float | None = None
    lane: str | None = None
    text: str = ""


def parse(line: str) -> Command | None:
    """One line -> a :class:`Command` (``None`` for blank lines and ``#`` comments).

    Raises :class:`ParameterError` (one line) for anything else.
    """
    text = line.split("#", 1)[0].strip()
    if not text:
        return None
    if text in ("help", "?"):
        return Command("help", text=text)
    if text == "status":
        return Command("status", text=text)
    if text == "mark" or text.startswith("mark "):
        return Command("mark", text=text, key=text[4:].strip() or None)
    m = _DRIVE.match(text)
    if m:
        if m.group("name") not in CONTROLLERS:
            raise ParameterError(f"unknown controller {m.group('name')!r}; available: {', '.join(sorted(CONTROLLERS))}")
        return Command("drive", m.group("name"), None, m.group("lane"), text)
    m = _ASSIGN.match(text)
    if not m:
        raise ParameterError(f"cannot read {text!r}; commands: {SYNTAX}")
    if m.group("lane") in DVS_PREFIXES:  # the camera's DVS: dvs.c_on = 0.2, bias.DiffBn = 4/39 (necviz.dvs_controls)
        key = m.group("key") if m.group("lane") == "dvs" else f"bias.{m.group('key')}"
        return Command("dvs", key, m.group("value"), None, text)
    from necviz.core.checks import parse_number

    return Command("set", m.group("key"), parse_number(m.group("key"), m.group("value")), m.group("lane"), text)


def keys(pipeline) -> dict[str, str]:
    """Every tunable key of the pipeline's lanes -> "unit: meaning" (for help and completion)."""
    out = {"c_on": "ln: P-TEDI ON threshold", "c_off": "ln: P-TEDI OFF threshold", "c": "ln: both thresholds"}
    for lane in pipeline.lanes.values():
        for name, t in lane.controller.tunables().items():
            out.setdefault(name, f"{t.unit}: {t.doc}")
    if pipeline.dvs.available:  # the camera's DVS biases
        from necviz.core.biases import CONTROLS

        out.update({f"dvs.{k}": v for k, v in CONTROLS.items()})
        out["bias.NAME"] = "COARSE/FINE: a raw coarse/fine bias (e.g. bias.DiffBn = 4/39)"
    return out


def help_text(pipeline) -> str:
    lines = [f"commands: {SYNTAX}", "keys:"]
    lines += [f"  {k:18s} {v}" for k, v in keys(pipeline).items()]
    lines.append(f"controllers: {', '.join(sorted(CONTROLLERS))}; lanes: {', '.join(pipeline.lanes)}")
    return "\n".join(lines)


def execute(pipeline, command: Command, timeout: float | None = 5.0) -> str:
    """Carry out ``command`` on ``pipeline``; returns the reply (raises NecvizError when refused).

    Waits up to ``timeout`` s for the streaming thread to apply a change; a change still queued
    then is reported as pending (it applies at the next packet).
    """
    if command.kind == "help":
        return help_text(pipeline)
    if command.kind == "status":
        return pipeline.status()
    if command.kind == "mark":
        fut = pipeline.submit(lambda p: mark(p, command.key or ""))
        try:
            return fut.result(timeout)
        except TimeoutError:
            return "mark: queued (applies at the next packet)"
    if command.kind == "dvs":
        fut = pipeline.tune_dvs(command.key, command.value)
        try:
            return fut.result(timeout)
        except TimeoutError:
            return f"{command.text}: queued (applies at the next packet)"
    if command.kind == "set":
        lanes = pipeline.lanes if command.lane is None else {command.lane: pipeline.lanes.get(command.lane)}
        if command.lane is not None and lanes[command.lane] is None:
            raise ParameterError(f"no lane {command.lane!r}; lanes: {', '.join(pipeline.lanes)}")
        if not any(command.key in ln.tunables() for ln in lanes.values()):
            raise ParameterError(f"unknown key {command.key!r}; keys: {', '.join(keys(pipeline))}")
        fut = pipeline.tune(command.key, command.value, command.lane)
    else:
        fut = pipeline.drive(command.key, command.lane)
    try:
        return fut.result(timeout)
    except TimeoutError:
        return f"{command.text}: queued (applies at the next packet)"


def mark(pipeline, text: str = "") -> tuple[str, dict]:
    """``mark``: every observer that keeps clips (:class:`~necviz.dashboard.flight_recorder.FlightRecorder`) opens
    one around this moment; the mark is also noted in the recording. Runs on the streaming thread."""
    replies = [r for r in (o.mark(text) for o in pipeline.observers) if r is not None]
    msg = "; ".join(replies) if replies else "mark noted in the recording (no --clips: no clip is written)"
    return f"mark{': ' + text if text else ''} — {msg}", {"mark": {"text": text}}


class _Reader:
    """Shared by the console and the file: run a line, report the reply or the refusal."""

    def __init__(self, pipeline, say):
        self.pipeline = pipeline
        self.say = say

    def line(self, text: str) -> None:
        try:
            command = parse(text)
            if command is None:
                return
            self.say(execute(self.pipeline, command))
        except NecvizError as e:
            self.say(f"error: {e}")


class TuningConsole:
    """Reads tuning commands on a daemon thread.

    On a terminal (``interactive``), a ``prompt_toolkit`` prompt keeps the typed line apart from
    the live status line (``status()``, refreshed twice a second below the prompt) and offers
    history and Tab completion; Ctrl-C stops the run (``on_interrupt``), Ctrl-D closes the prompt.
    Otherwise (a pipe, a test) each line of ``stream`` is read as it comes.
    """

    def __init__(
        self,
        pipeline,
        stream=None,
        out=None,
        status=None,
        on_interrupt=None,
        interactive: bool | None = None,
        pt_input=None,
        pt_output=None,
    ):
        self.pipeline = pipeline
        self.stream = stream if stream is not None else sys.stdin
        self.out = out if out is not None else sys.stdout
        self.status = status
        self.on_interrupt = on_interrupt
        if interactive is None:
            interactive = pt_input is not None or (
                hasattr(self.stream, "isatty") and self.stream.isatty() and sys.stdout.isatty()
            )
        self.interactive = bool(interactive)
        self._pt_input, self._pt_output = pt_input, pt_output
        self._session = None
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="necviz-tuning", daemon=True)

    def start(self) -> TuningConsole:
        self._thread.start()
        return self

    def close(self, timeout: float = 2.0) -> None:
        """End the prompt (the run is over)."""
        self._closed.set()
        app = getattr(self._session, "app", None)
        if app is not None and app.is_running and app.loop is not None:
            app.loop.call_soon_threadsafe(lambda: app.exit() if app.is_running else None)
        self._thread.join(timeout)

    def _say_plain(self, msg: str) -> None:
        print(f"\n  tune: {msg}", file=self.out, flush=True)

    def _run(self) -> None:
        if self.interactive:
            self._run_prompt()
        else:
            reader = _Reader(self.pipeline, self._say_plain)
            for line in self.stream:
                if self._closed.is_set():
                    break
                reader.line(line)

    def completer(self):
        from prompt_toolkit.completion import WordCompleter

        words = ["help", "status", "set", "drive", "mark", *sorted(CONTROLLERS), *keys(self.pipeline)]
        words += [f"{lane}.{k}" for lane, ln in self.pipeline.lanes.items() for k in ln.tunables()]
        words += list(self.pipeline.lanes)
        if self.pipeline.dvs.available:  # the camera's bias names (bias.DIFFBN = 4/39)
            from necviz.core.biases import BIAS_ADDRESSES, family_of

            family = family_of(self.pipeline.source.dvs_family)
            words += [f"bias.{n}" for n in BIAS_ADDRESSES[family]]
        return WordCompleter(sorted(set(words), key=words.index), WORD=True)

    def _run_prompt(self) -> None:
        from prompt_toolkit import PromptSession
        from prompt_toolkit.history import InMemoryHistory
        from prompt_toolkit.shortcuts import print_formatted_text

        def say(msg: str) -> None:
            print_formatted_text(f"  tune: {msg}", output=self._pt_output)

        reader = _Reader(self.pipeline, say)
        self._session = PromptSession(
            history=InMemoryHistory(),
            completer=self.completer(),
            complete_while_typing=False,
            bottom_toolbar=(lambda: self.status()) if self.status is not None else None,
            refresh_interval=0.5,
            input=self._pt_input,
            output=self._pt_output,
        )
        while not self._closed.is_set():
            try:
                text = self._session.prompt("tune> ")
            except KeyboardInterrupt:
                if self.on_interrupt is not None:
                    self.on_interrupt()
                break
            except EOFError:
                break
            if text is None or self._closed.is_set():
                break
            reader.line(text)


class TuningFile:
    """Watches a ``key = value`` file; applies the lines that changed each time it is saved."""

    def __init__(self, pipeline, path: str | Path, out=None, poll_s: float = 0.5):
        self.pipeline = pipeline
        self.path = Path(path)
        if not self.path.is_file():
            raise ParameterError(f"--tune-file: {str(self.path)!r} is not a file")
        self.out = out if out is not None else sys.stderr
        self.poll_s = float(poll_s)
        self._seen: dict[str, str] = {}
        self._mtime = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="necviz-tune-file", daemon=True)

    def start(self) -> TuningFile:
        self.check()  # the file's current content applies at once
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def check(self) -> int:
        """Submit the lines that changed since the last check (if the file changed); returns how many."""
        try:
            mtime = os.stat(self.path).st_mtime_ns
        except OSError:
            return 0
        if mtime == self._mtime:
            return 0
        self._mtime = mtime
        n = 0
        for line in self.path.read_text(encoding="utf-8", errors="replace").splitlines():
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            key = re.split(r"\s*=\s*|\s+", text.removeprefix("set ").strip(), maxsplit=1)[0]
            if self._seen.get(key) == text:
                continue
            self._seen[key] = text
            try:
                command = parse(text)
            except ParameterError as e:
                print(f"\n  tune: {self.path.name}: error: {e}", file=self.out, flush=True)
                continue
            if command is None:
                continue
            n += 1
            if command.kind in ("set", "drive", "dvs"):
                fut = (
                    self.pipeline.tune(command.key, command.value, command.lane)
                    if command.kind == "set"
                    else self.pipeline.tune_dvs(command.key, command.value)
                    if command.kind == "dvs"
                    else self.pipeline.drive(command.key, command.lane)
                )
                fut.add_done_callback(self._report)
        return n

    def _report(self, fut) -> None:
        e = fut.exception()
        print(f"\n  tune: {self.path.name}: {('error: ' + str(e)) if e else fut.result()}", file=self.out, flush=True)

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            self.check()


__all__ = [
    "Command",
    "SYNTAX",
    "THRESHOLD_KEYS",
    "TuningConsole",
    "TuningFile",
    "execute",
    "help_text",
    "keys",
    "mark",
    "parse",
]
