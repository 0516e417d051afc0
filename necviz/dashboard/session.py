"""What ``demo``, ``replay``, ``live`` and ``sweep show`` share: open the viewer, run the loop, show progress.

In Rerun's own shape (its examples: parse the arguments, ``rr.script_setup(args, ...,
default_blueprint=...)``, a plain run function): a command builds its source, its lanes and its
blueprint and calls :func:`run`, which opens the Rerun recording the
:class:`~necviz.options.ViewerOptions` ask for (``script_setup``'s part), logs run properties and
series styles, runs the :class:`~necviz.pipeline.Pipeline` on its streaming thread with a
:class:`~necviz.dashboard.sink.RerunSink` (and a native recorder, if asked), offers live tuning (a
prompt and/or a watched file), shows a live count until the source ends or Ctrl-C, then flushes
everything and prints a summary.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field, replace

import rerun as rr
import rerun.blueprint as rrb

from necviz.dashboard.sink import RerunSink, SinkOptions
from necviz.dashboard.tuning import TuningConsole, TuningFile
from necviz.dashboard.viewer import FILE_FLUSH_S, open_viewer, text
from necviz.drivers.source import Source
from necviz.layouts import style_series
from necviz.memory import bound_heap_retention
from necviz.options import ShowOptions, TuneOptions, ViewerOptions
from necviz.outputs import Output, OutputError, RecordingFile, StreamedOutput
from necviz.pipeline import DiskWatch, Lane, Observer, Pipeline, RecorderObserver
from necviz.progress import LiveLine, output
from necviz.wording import BEHIND, print_summary

# -- pace: did a paced run keep the speed it was asked for? ------------------------------------------
# A run asked for ``--speed 1`` (or watched in a viewer) feeds packets at real-time pace; on a busy machine
# it may not keep up, and then its latency and recovery times are not real-time figures. PaceWatch notes
# the wall time of the first packet (when the pipeline's pacing clock starts; compilation before it does
# not count); the live count shows the speed achieved when it falls below necviz.wording.BEHIND of the
# speed asked, and the summary says it in one phrase (necviz.wording.pace_note).

#: Wall seconds before a running figure is shown (the first second is mostly start-up jitter).
SETTLE_S = 2.0


class PaceWatch(Observer):
    """Wall time since the run's first packet (``started``); ``None`` before it."""

    name = "pace"

    def __init__(self) -> None:
        self.wall0: float | None = None

    def started(self, t_us: int, initial: dict) -> None:
        self.wall0 = time.perf_counter()

    def wall_s(self) -> float | None:
        return None if self.wall0 is None else time.perf_counter() - self.wall0


def achieved_speed(sensor_s: float, wall_s: float | None, settle_s: float = 0.0) -> float | None:
    """Sensor seconds per wall second (1 = real time); None before ``settle_s`` of wall time or any sensor time."""
    if wall_s is None or wall_s <= settle_s or wall_s <= 0 or sensor_s <= 0:
        return None
    return sensor_s / wall_s


@dataclass(kw_only=True)
class Session:
    """One dashboard run: a source, its lanes and how to show them.

    ``layout``: the name of ``blueprint``'s layout (the run's properties, a clip's own layout).
    ``record``: a native recording (``.necrec``, :class:`~necviz.outputs.RecordingFile`) of
    ``record_camera`` (default: the first lane's camera) storing ``record_properties`` (default:
    ``properties``); the run opens it beside the viewer's ``--save`` file (``recorder``) and commits or
    discards both with the run. ``lossless``: keep every frame and event image when the
    run is not paced (a simulation or replay into a file). ``history``: frames of per-frame
    telemetry kept per lane (``None``: all). ``origin_us``: sensor time shown as 0.
    ``keep_partial``: if the run fails, keep what the output files hold (a camera session, which
    cannot be produced again) instead of deleting them.
    """

    command: str
    layout: str
    title: str
    properties: dict
    #: what :func:`run` is given: the source, its lanes, the viewer options and the command's blueprint
    source: Source | None = None
    lanes: list[Lane] = field(default_factory=list)
    viewer: ViewerOptions = field(default_factory=ViewerOptions)
    blueprint: rrb.Blueprint | None = None
    show: ShowOptions = field(default_factory=ShowOptions)
    tune: TuneOptions | None = None
    record: str | os.PathLike | None = None  # the native recording (--record)
    record_properties: dict | None = None
    record_camera: str | None = None
    lossless: bool = True
    history: int | None = None
    origin_us: int = 0
    expected_duration_s: float | None = None
    stop_after_s: float | None = None
    #: more observers (the flight recorder, the video writer): factories ``f(session, layout, out)``
    observers: list = field(default_factory=list)
    keep_partial: bool = False
    before_commit: object = None  # callable(stats): last step of a run (e.g. write --json); raising fails it
    #: the native recorder of ``record``, opened by the run with the other outputs (:func:`run_session`)
    recorder: RecordingFile | None = field(default=None, init=False)


def run(
    source: Source,
    lanes: list[Lane],
    viewer: ViewerOptions,
    blueprint: rrb.Blueprint,
    session: Session,
    out=...,
    stdin=None,
) -> dict:
    """Show ``source`` driven by ``lanes`` in the viewer ``viewer`` asks for, laid out by ``blueprint``, and
    return the run's summary: a command's one call into the dashboard. ``session``: the rest (the command's
    name, properties, tuning, recorder, observers ...); ``out``: where progress and the summary go;
    ``stdin``: tuning commands. See :func:`run_session`."""
    return run_session(
        replace(session, source=source, lanes=list(lanes), viewer=viewer, blueprint=blueprint), out, stdin
    )


def run_session(session: Session, out=..., stdin=None) -> dict:
    """Run the session; returns the pipeline's summary (with ``"rrd"``, the file written, if any).

    Output files are committed only when the run succeeded. On any failure the source and the
    recorder are closed (a camera does not keep streaming) and the files being written are deleted
    (:class:`~necviz.outputs.StreamedOutput`) — or kept, readable, when ``session.keep_partial`` —
    and the error's one line says which.
    """
    from necviz.outputs import failure_note

    out = output(out)
    bound_heap_retention()  # a burst of events must not stay resident for the rest of a long session
    outputs: list[Output] = []  # what to commit or discard: the recorder, the viewer's --save file (_open)
    try:
        stats, viewer = _run(session, out, stdin, outputs)
        if session.before_commit is not None:
            session.before_commit(stats)
        for o in outputs:
            o.commit()
    except BaseException as e:
        if session.recorder is not None and not session.recorder.closed:
            try:
                session.recorder.close()
            except BaseException:  # noqa: BLE001 - a full disk: the run's error (or this one) is reported
                pass
        try:
            session.source.close()
        except BaseException:  # noqa: BLE001
            pass
        notes = []
        for o in outputs:
            try:
                notes.append(o.discard())
            except OSError:
                pass
        if session.keep_partial:
            for o in outputs:
                kept = o.path
                if kept is not None and os.path.exists(kept) and out is not None:
                    print(f"  recording so far: {kept}", file=out)
        new = failure_note(e, notes)
        if new is e:
            raise
        raise new from None
    if session.recorder is not None and out is not None:
        rec = session.recorder.path
        print(f"  recorded to {rec} (replay it with: necviz replay {rec})", file=out)
    if viewer.save_path is not None and out is not None:
        print(f"  recording: {viewer.save_path} (open it with: rerun {viewer.save_path})", file=out)
    if viewer.url is not None:
        _keep_serving(viewer, out)
    return stats


def lane_labels(lanes) -> dict[str, str]:
    """The name each lane is shown by where it is not its controller's (``camera`` in ``live`` and
    ``replay`` is shown as ``nec``, ``navid``, …), so the views and curves say which controller they show."""
    out = {}
    for ln in lanes:
        ctrl = ln.controller.name
        if ctrl and ctrl != "base" and ctrl != ln.name:
            out[ln.name] = ctrl
    return out


def _run(ss: Session, out, stdin, outputs: list) -> dict:
    """Stream the session (:func:`_stream`: the viewer, the pipeline and its observers, the loop until the
    source ends, Ctrl-C, a full disk or a failed output), then say how it went."""
    speed = ss.show.speed
    if speed == "auto":
        speed = 1.0 if ss.viewer.watched else None
    stats, viewer, pipe, observers, disk_full, pace_wall = _stream(ss, out, stdin, outputs, speed)
    broken = _failed(observers)
    if broken is not None:  # an output that could not be written (a clip on a full disk)
        at = (pipe.now_us or 0) / 1e6 - (pipe.first_us or 0) / 1e6
        raise type(broken)(f"{broken}; the run was stopped at {at:.1f} s")
    if disk_full is not None:
        path, free = disk_full
        raise OutputError(
            f"the disk holding {path} is nearly full ({free >> 20} MB free): the run was stopped at "
            f"{(pipe.now_us or 0) / 1e6 - (pipe.first_us or 0) / 1e6:.1f} s so the files end whole"
        )
    source_stats = ss.source.stats
    if "dropped_events" in source_stats:  # a camera: what the device lost
        stats["source"] = {k: v for k, v in source_stats.items() if isinstance(v, (int, float))}
    sensor_s = ((pipe.now_us or 0) - (pipe.first_us or 0)) / 1e6
    stats["speed"] = speed
    stats["achieved_speed"] = achieved_speed(sensor_s, pace_wall)
    print_summary(out, stats)  # with a note when the run fell behind the speed asked
    stats["rrd"] = str(viewer.save_path) if viewer.save_path is not None else None
    stats["telemetry"] = pipe.telemetry
    return stats, viewer


def _stream(ss: Session, out, stdin, outputs: list, speed):
    """Open the viewer and its sink (:func:`_open`), build the pipeline over the session's source and lanes
    with its observers (the sink, the native recorder, the command's own, a pace watch; the camera's DVS
    set as ``--dvs`` asks, P-TEDI following a recording's bias changes), run it with live tuning (a
    prompt, a watched file) and a live count until the source ends, Ctrl-C, a nearly full disk or a failed
    output; then finish it and close the viewer. Returns the pipeline's summary, the viewer, the pipeline,
    its observers, ``(file, bytes free)`` when the disk stopped the run (else None) and the wall seconds
    from the first packet to the end of the loop."""
    pace = PaceWatch()  # a paced run that cannot keep its speed says so (status, the summary)
    t0 = time.perf_counter()  # set again when the loop starts

    def sensor_s() -> float:
        return ((pipe.now_us or 0) - (pipe.first_us or 0)) / 1e6

    def status() -> str:  # the live count (or the prompt's status bar)
        got = achieved_speed(sensor_s(), pace.wall_s(), SETTLE_S)
        behind = speed is not None and got is not None and got < BEHIND * speed  # as the summary's pace_note
        line = progress_line(ss.command, pipe, ss.expected_duration_s, time.perf_counter() - t0)
        return line + (f" · behind: {got:.2f}x real time" if behind else "")

    viewer, sink = _open(ss, out, outputs, speed)
    observers = [sink]  # then the native recorder (--record), the command's own, the pace and disk watches
    if ss.recorder is not None:
        cam = ss.record_camera or ss.lanes[0].camera or ss.lanes[0].name
        driver = next((ln.name for ln in ss.lanes if ln.drives and (ln.camera or ln.name) == cam), cam)
        observers.append(RecorderObserver(ss.recorder, cam, driver))
    observers += [make(ss, ss.layout, out) for make in ss.observers]
    files = [f for f in (viewer.save_path, ss.recorder.path if ss.recorder is not None else None) if f is not None]
    files += [o.folder for o in observers if o.folder is not None]  # clips fill a disk too
    disk = DiskWatch(files, viewer.segments)
    observers += [pace, disk]
    pipe = Pipeline(
        ss.source,
        ss.lanes,
        history=ss.history,
        observers=observers,
        speed=speed,
        stop_after_s=ss.stop_after_s,
    )
    for key, value in ss.tune.dvs if ss.tune is not None else ():  # --dvs: on the camera before its first packet
        msg, data = pipe.dvs.set(key, value, None, started=False)
        if out is not None:
            print(f"  {msg}", file=out)
        pipe.submit(lambda p, m=msg, d=data: (m, d))  # noted in the recordings at the first packet
    notes = list(ss.source.annotations)  # a native recording: P-TEDI follows its recorded bias changes
    if notes and pipe.dvs.follow_recording(notes) and out is not None:
        print(f"  P-TEDI follows the {len(pipe.dvs.scheduled)} DVS bias change(s) recorded in the file", file=out)
    tune_file = console = None
    t0 = time.perf_counter()
    disk_full = None  # (file, bytes free) when the run was stopped to keep its files whole
    pace_wall = None  # wall seconds from the first packet to the end of the loop
    try:
        if ss.tune is not None and ss.tune.file:
            tune_file = TuningFile(pipe, ss.tune.file, out=out)
        stream = stdin if stdin is not None else sys.stdin
        if (
            ss.tune is not None
            and ss.tune.prompt
            and stream is not None
            and (stdin is not None or (hasattr(stream, "isatty") and stream.isatty()))
        ):
            console = TuningConsole(pipe, stream, out=out, status=status, on_interrupt=pipe.stop)
        pipe.start()
        if tune_file is not None:
            tune_file.start()
        if console is not None:
            if not console.interactive:
                print("  tuning: type commands and Enter (help lists them)", file=out)
            console.start()
        line = LiveLine(out if console is None or not console.interactive else None)  # else: the prompt's status bar
        try:
            while not pipe.wait(0.5):
                line.show(status())
                disk_full = disk.full
                broken = _failed(pipe.observers)
                if disk_full is not None or broken is not None:  # stop while the files can still be completed
                    pipe.stop()
                    break
        except KeyboardInterrupt:
            print("\n  stopping (Ctrl-C): flushing the recording…", file=out, flush=True)
            pipe.stop()
        if console is not None:
            console.close()
        pace_wall = pace.wall_s()
        if out is not None:
            line.clear()
            print(status(), file=out, flush=True)
    finally:
        if tune_file is not None:
            tune_file.stop()
        failed = True
        try:
            stats = pipe.finish()
            failed = False
        finally:
            try:
                viewer.close()
            except BaseException:
                if not failed and disk_full is None:
                    raise  # else the run's own error (or the disk guard's, below) is the one reported
    return stats, viewer, pipe, observers, disk_full, pace_wall


def _open(ss: Session, out, outputs: list, speed):
    """Open the viewer with the command's blueprint (``rr.script_setup``'s part), log the run's properties
    and series styles, and make the Rerun sink that logs the run into it; the ``--save`` file joins
    ``outputs``. Returns ``(viewer, sink)``."""
    v = ss.viewer
    names = [lane.name for lane in ss.lanes]
    labels = lane_labels(ss.lanes)
    lossless = ss.lossless and speed is None and not v.watched
    # a live session only saved to a file: series in 2 s chunks (Rerun's file sink indexes every chunk)
    flush = FILE_FLUSH_S if not (lossless or v.watched) else None
    sink_options = SinkOptions(
        event_window_us=int(ss.show.event_window_ms * 1000),
        raw_points=ss.show.event_points,
        origin_us=ss.origin_us,
        lossless=lossless,
        flush_period_s=flush,
        image_period_us=0 if ss.show.image_rate_hz is None else int(round(1e6 / ss.show.image_rate_hz)),
    )
    # the outputs, made together: the native recording (--record), then the viewer's --save file; each is
    # committed or discarded with the run from the moment it exists
    if ss.record is not None:
        props = ss.record_properties if ss.record_properties is not None else ss.properties
        ss.recorder = RecordingFile(ss.record, ss.source.sensor, props, keep_partial=ss.keep_partial)
        outputs.append(ss.recorder)
    save = StreamedOutput(v.save, keep_partial=ss.keep_partial, flag="--save") if v.save else None
    viewer = open_viewer(v, ss.blueprint, ss.title, output=save)
    if viewer.output is not None:  # the --save file: committed or discarded with the run
        outputs.append(viewer)
    for m in viewer.messages:
        print(f"  {m}", file=out)
    rec = viewer.rec
    rec.send_property("run", rr.AnyValues(**{k: text(val) for k, val in ss.properties.items()}, layout=ss.layout))
    style_series(rec, names, labels)
    sensor = ss.source.sensor
    sink = RerunSink(rec, names, sensor.height, sensor.width, sink_options)
    sink.files = viewer.files
    sink.rotate = viewer.rotate
    return viewer, sink


def _failed(observers):
    """The error of an observer whose output could not be written (its ``failure``), or None."""
    return next((o.failure for o in observers if o.failure is not None), None)


def _keep_serving(viewer, out) -> None:
    """The run is over but the web viewer is still being watched: serve until Ctrl-C (or SIGTERM)."""
    print(f"  still serving the recording at {viewer.url}; press Ctrl-C to stop", file=out, flush=True)
    try:
        while viewer.server is not None and viewer.server.poll() is None:
            time.sleep(0.5)
    except KeyboardInterrupt:
        print("  stopped serving", file=out)
    finally:
        viewer.stop_serving()


def progress_line(command: str, pipe: Pipeline, expected: float | None, wall: float) -> str:
    t = ((pipe.now_us or 0) - (pipe.first_us or 0)) / 1e6
    of = f"/{expected:g}" if expected else ""
    return (
        f"  {command}: {t:6.2f}{of} s sensor time · {pipe.events / 1e6:7.2f} M events · {pipe.frames} frames"
        f" · {wall:5.1f} s"
    )
