"""``necviz live``: a DAVIS camera with a controller closing the loop, in the ``live`` layout.

``device="usb"`` opens a real DAVIS346/DAVIS240 (pyusb); ``device="dv"`` opens it through iniVation's
dv-processing instead (:mod:`necviz.drivers.dv_camera`); ``device="emulated"`` runs the pyusb driver
against a virtual DAVIS346 fed by the simulator (no hardware). The controller drives the
camera: every command goes to the APS exposure register between frames. While it runs, the
terminal prompt (or a tuning file) changes parameters and ``drive NAME`` switches controller.

If the camera is unplugged, everything recorded so far is flushed (the ``.rrd`` and the
``--record`` file stay readable) and the run ends with a one-line error — or, with
``reconnect``, waits for the camera to come back. Per-frame telemetry keeps the last
``LiveOptions.history`` frames, so memory does not grow with the length of a session.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from necviz.commands import Command
from necviz.commands.args import (
    add_clip_args,
    add_scene_args,
    add_show_args,
    clip_options,
    controller_choices,
    scene_options,
    show_options,
    tune_options,
)
from necviz.core.errors import ParameterError
from necviz.progress import output

if TYPE_CHECKING:
    from necviz.drivers.davis.emulator import EmulatedDavis346
    from necviz.options import LiveOptions, ViewerOptions

LANE = "camera"
#: the reader's queue holds at most this much sensor time beyond what the loop has taken: one frame interval (20 ms),
#: so a command is never computed from data older than the frame being exposed (beyond it the device drops, counts
#: and the summary reports; measured in benchmarks/live_reaction.py: with 0.1 s the backlog reached 50 ms at
#: --speed 4 and commands landed 2 frames late)
LIVE_LAG_S = 0.02
#: at --speed max the emulated sensor runs as fast as it is read; its reader stays within this much sensor time
#: of what the pipeline has taken (a few ms: well within one frame), so it never runs ahead of the loop
MAX_SPEED_LAG_S = 0.005


def run(options: LiveOptions | None = None, viewer: ViewerOptions | None = None, out=..., stdin=None) -> dict:
    """Run a DAVIS camera (USB or emulated) with a controller closing the loop, with live tuning.

    Parameters
    ----------
    options : LiveOptions, optional
        The device, the controller, duration, recordings, clips (default: ``LiveOptions()``).
    viewer : ViewerOptions, optional
        Where the Rerun data goes (default: a native viewer with a display, else a file).
    out : file, optional
        Where progress and the summary are printed (default: standard output; ``None``: nothing).
    stdin : file, optional
        Where tuning commands are read from (default: the terminal, when interactive).

    Returns
    -------
    dict
        The run's summary (see :func:`necviz.dashboard.session.run`).

    Raises
    ------
    DeviceError
        No camera, the wrong firmware, no permission; an unplug without ``reconnect`` (after
        everything decoded was processed and the recordings were flushed).
    ParameterError
        Bad options or output files.
    """
    from necviz.core.control import make_controller
    from necviz.dashboard import session as dashboard
    from necviz.dashboard.flight_recorder import clip_observer
    from necviz.dashboard.session import Session, lane_labels
    from necviz.dashboard.viewer import resolve
    from necviz.layouts import make_blueprint
    from necviz.options import LiveOptions, ViewerOptions
    from necviz.outputs import write_json
    from necviz.pipeline import Lane
    from necviz.profiles import load_profile

    out = output(out)
    options = options or LiveOptions()
    if options.device == "emulated":  # the scene's --set values against the run's duration, before anything opens
        from necviz.drivers.sim.scenes import make_scenario

        spec = options.scene.spec()
        make_scenario(
            spec["name"],
            duration_us=None if options.duration_s is None else int(round(options.duration_s * 1e6)),
            seed=options.scene.resolved_seed,
            **{**spec["params"], **options.scene.params},
        )
    viewer = resolve(viewer or ViewerOptions(), "live")  # the headless default filled in
    options.check_outputs(viewer)  # before the camera is opened
    profile = load_profile(options.profile) if options.profile is not None else None
    if options.clips is not None:
        options.clips.check()
    from necviz.drivers.davis import CameraOptions, open_camera

    if viewer.save is not None:  # a long session's file grows by GB an hour: say so before it fills a disk
        from necviz.dashboard.rrd_file import size_warning

        note = size_warning(viewer.save, options.duration_s, options.show.image_rate_hz)
        if note is not None and out is not None:
            print(note, file=out)
    speed = options.show.speed
    if speed == "auto":  # as the session resolves it: real time when a viewer watches
        speed = 1.0 if viewer.watched else None
    backend = None
    n_transfers, transfer_size = options.usb_transfers or (None, None)
    usb = {"usb": options.usb, "transfer_size": transfer_size, **({"transfers": n_transfers} if n_transfers else {})}
    camera_options = CameraOptions(reconnect=options.reconnect, buffer_s=LIVE_LAG_S, **usb)
    if options.device == "emulated":
        from necviz.drivers.davis.emulator import EmulatedDavis346, EmulatorOptions, Faults

        spec = options.scene.spec()
        faults = Faults(unplug_after_s=options.emulate_unplug_s) if options.emulate_unplug_s is not None else None
        # the emulated sensor is paced as a sensor at every speed: on the wall clock scaled by --speed, or, at
        # --speed max, by its reader, which stays within MAX_SPEED_LAG_S of sensor time of the pipeline
        emulated = EmulatorOptions(
            scenario=spec["name"],
            seed=options.scene.resolved_seed,
            duration_s=options.duration_s,
            scenario_params={**spec["params"], **options.scene.params},
            realtime=speed is not None,
            time_scale=1.0 if speed is None else float(speed),
        )
        backend = EmulatedDavis346(emulated, faults)
        if speed is None:
            camera_options = CameraOptions(reconnect=options.reconnect, buffer_s=MAX_SPEED_LAG_S, **usb)
    if options.device == "dv":
        from necviz.drivers.dv_camera import open_dv_camera

        if options.reconnect:
            raise ParameterError("--reconnect works with necviz's driver (--device usb), not with --device dv")

        camera = open_dv_camera(options.serial, options=CameraOptions())
    else:
        camera = open_camera(options.device, options.serial, options=camera_options, backend=backend)
    info, limits, sensor = camera.info, camera.limits, camera.sensor
    kw = {} if profile is None else {"tedi": profile.tedi, "crf": profile.crf}
    rate = camera.camera_info.event_rate_max  # the device's event bus ceiling (NEC's escape rule)
    lane = Lane(LANE, make_controller(options.controller, sensor=sensor, limits=limits, event_rate_max=rate, **kw))
    props = {
        "command": "live",
        "device": options.device,
        "serial": info.get("serial"),
        "firmware": info.get("firmware"),
        "logic": info.get("logic_version", info.get("logic")),
        "controller": options.controller,
        "camera_limits": limits,
        "camera_profile": str(options.profile) if options.profile else "default DAVIS346 response",
        **({"scenario": options.scene.name} if options.device == "emulated" else {}),
    }
    print(
        f"  live: {sensor.name or 'DAVIS'} {info.get('serial', '')} ({options.device}), {options.controller} drives "
        f"the exposure ({limits.exposure_min_us:g}..{limits.exposure_max_us:g} µs, digital gain ≤ "
        f"{limits.gain_max:g})",
        file=out,
    )
    record_props = dict(props)  # the recording's properties, as the camera was opened
    props["speed"] = "max" if speed is None else speed

    def write_summary(stats):  # before the recordings are committed: a file that cannot be written fails the run
        if options.json is not None:
            write_json(
                options.json,
                live_summary(stats, props, backend, getattr(camera, "usb_transfers", None)),
                indent=1,
                flag="--json",
            )

    layout = viewer.layout or "live"
    settings = Session(
        command="live",
        layout=layout,
        title=f"necviz live: {info.get('serial', '')}",
        properties=props,
        show=options.show,
        tune=options.tune,
        record=options.record,  # a camera session cannot be recorded again: kept if it fails (keep_partial)
        record_properties=record_props,
        record_camera=LANE,
        lossless=False,
        history=options.history,
        expected_duration_s=options.duration_s,
        stop_after_s=options.duration_s,
        keep_partial=True,
        observers=[clip_observer(options.clips)] if options.clips is not None else [],
        before_commit=write_summary,
    )
    blueprint = make_blueprint(layout, [LANE], sensor.width, sensor.height, lane_labels([lane]))
    stats = dashboard.run(camera, [lane], viewer, blueprint, settings, out, stdin)
    slip = backend.clock_slip_us if backend is not None else 0
    if slip and out is not None:  # the emulated sensor could not keep up with the wall clock: say how far it slipped
        print(
            f"  emulated sensor: its simulation fell {slip / 1e6:.2f} s behind the wall clock; the sensor's clock "
            "slipped by as much (it never sends stale time in bulk)",
            file=out,
        )
    if options.json is not None and out is not None:
        print(f"  wrote {options.json}", file=out)
    return stats


def live_summary(
    stats: dict, properties: dict | None = None, backend: EmulatedDavis346 | None = None, usb: dict | None = None
) -> dict:
    """The JSON of ``live --json``: the run, then per lane its frames, saturated frames (> 50 % clipped),
    events, commands, the processing latency (packet out of the source -> command handed back, wall µs) and
    the reaction in sensor time (:mod:`necviz.reaction`): ``frames_late`` p50/p99/max and
    ``command_to_exposure_us`` p50/p99 over the exposure changes that reached a frame; the reader's deepest
    backlog and how often it held back; how necviz's driver read the camera (``usb``: library, transfers in flight
    and their bytes; absent for ``--device dv``); for the emulated camera, how far its clock slipped behind the wall
    clock and the frames its full FIFO kept from being exposed."""

    def num(v):
        return None if v is None or (isinstance(v, float) and v != v) else v

    lanes = {}
    for name, s in stats["lanes"].items():
        r = s.get("reaction") or {}
        late, lag = r.get("frames_late", {}), r.get("command_to_exposure_us", {})
        lanes[name] = {
            "frames": s["frames"],
            "saturated_frames": s["saturated_frames_50"],
            "events": stats["events"],
            "commands": s["commands"],
            "exposure_changes": r.get("changes"),
            "changes_applied": r.get("applied"),
            "changes_superseded": r.get("superseded"),
            "processing_latency_p50_us": num(s["latency_p50_us"]),
            "processing_latency_p99_us": num(s["latency_p99_us"]),
            "frames_late": {k: late.get(k) for k in ("p50", "p99", "max")},
            "command_to_exposure_us": {k: lag.get(k) for k in ("p50", "p99")},
        }
        if "ptedi" in s:  # the contrast thresholds P-TEDI used (they follow the DVS biases), beside its events
            lanes[name]["ptedi"] = {k: s["ptedi"][k] for k in ("c_on", "c_off")}
    src = stats.get("source") or {}
    props = {k: v for k, v in (properties or {}).items() if isinstance(v, (str, int, float, bool)) or v is None}
    return {
        "run": props,
        "duration_s": stats["duration_s"],
        "wall_s": stats["wall_s"],
        "events": stats["events"],
        "frames": stats["frames"],
        **({"usb": dict(usb)} if usb else {}),
        "reader": {
            k: src[k]
            for k in (
                "lag_peak_us",
                "backpressure_events",
                "backpressure_s",
                "dropped_events",
                "queue_peak_bytes",
                "transfers",
                "timeouts",
                "out_of_order",
            )
            if k in src
        },
        "lanes": lanes,
        **({"dvs": stats["dvs"]} if "dvs" in stats else {}),
        **(
            {"emulator": {"clock_slip_s": backend.clock_slip_us / 1e6, "frames_skipped": backend.frames_skipped}}
            if backend is not None
            else {}
        ),
    }


def _usb_transfers(text):
    """``--usb-transfers N,BYTES``: checked, or a one-line argparse error."""
    import argparse

    from necviz.core.errors import ParameterError
    from necviz.drivers.davis.transfers import parse_transfers

    try:
        return parse_transfers(text)
    except ParameterError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_arguments(p) -> None:
    from necviz.flags import number

    p.add_argument(
        "--device",
        choices=("usb", "dv", "emulated"),
        default="usb",
        help="usb (a real camera, necviz's driver), dv (the same camera through iniVation's dv-processing: "
        "pip install 'necviz[dv]') or emulated (necviz's driver on a virtual DAVIS346)",
    )
    p.add_argument("--serial", default=None, help="which camera when several are attached")
    p.add_argument("--reconnect", action="store_true", help="if the camera is unplugged, wait for it to return")
    p.add_argument(
        "--usb",
        choices=("single", "auto", "libusb1", "pyusb"),
        default="single",
        help="how necviz's driver reads the camera: single (default: one 256 KiB read in flight), libusb1 "
        "(asynchronous transfers in flight, as libcaer: pip install 'necviz[usb]'), pyusb (reads of 8 KiB on a "
        "thread of their own) or auto (libusb1 if installed, else pyusb)",
    )
    p.add_argument(
        "--usb-transfers",
        type=_usb_transfers,
        default=None,
        metavar="N,BYTES",
        help="with --usb libusb1, pyusb or auto: transfers in flight and bytes each, whole 1024-byte packets "
        "(default 32,8192: libcaer's 8 KiB transfers, more of them in flight; e.g. 8,8k as libcaer)",
    )
    p.add_argument(
        "--controller",
        default="nec",
        choices=controller_choices(),
        help="the controller that drives the camera (default nec)",
    )
    p.add_argument(
        "--duration",
        type=number("--duration", "live"),
        default=None,
        metavar="S",
        help="stop after S seconds of sensor time (emulated: the scene's length)",
    )
    p.add_argument(
        "--emulate-unplug",
        type=number("--emulate-unplug"),
        default=None,
        metavar="S",
        help="emulated device: unplug it after S seconds (shows what an unplug does)",
    )
    p.add_argument(
        "--record", metavar="FILE.necrec", help="record events, frames and commands to a crash-safe native file"
    )
    p.add_argument(
        "--json",
        metavar="FILE",
        help="write the summary per lane as JSON (frames, saturated frames, events, commands, processing latency, "
        "frames late and command-to-exposure time in sensor time)",
    )
    add_scene_args(p, emulated=True)
    add_show_args(p)
    add_clip_args(p)


def _command(args) -> int:
    from necviz.dashboard.viewer_flags import viewer_options
    from necviz.options import LiveOptions

    run(
        LiveOptions(
            args.device,
            serial=args.serial,
            reconnect=args.reconnect,
            controller=args.controller,
            duration_s=args.duration,
            scene=scene_options(args, scene_duration=False),
            emulate_unplug_s=args.emulate_unplug,
            usb=args.usb,
            usb_transfers=args.usb_transfers,
            record=args.record,
            force=args.force,
            profile=args.profile,
            show=show_options(args),
            tune=tune_options(args),
            clips=clip_options(args),
            json=args.json,
        ),
        viewer_options(args),
    )
    return 0


COMMAND = Command(
    name="live",
    help="a DAVIS camera (USB or emulated) with NEC closing the loop",
    description="Runs a controller (NEC by default) in closed loop on a DAVIS346/DAVIS240 over "
    "USB (necviz's driver, or iniVation's dv-processing with --device dv), or on a virtual DAVIS346 "
    "(--device emulated), in the live layout.",
    add_arguments=add_arguments,
    run=_command,
)
