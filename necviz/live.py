"""``necviz live``: a DAVIS camera with NEC closing the loop, in the ``live`` layout.

``--device usb`` opens a real DAVIS346/DAVIS240 (pyusb); ``--device emulated`` runs the same
driver against a virtual DAVIS346 fed by the simulator (no hardware). The controller drives the
camera: every command goes to the APS exposure register between frames. While it runs, the
terminal prompt (or ``--tune-file``) changes parameters and ``drive NAME`` switches controller.

If the camera is unplugged, everything recorded so far is flushed (the ``.rrd`` and the
``--record`` file stay readable) and the command ends with a one-line error — or, with
``--reconnect``, waits for the camera to come back.
"""

from __future__ import annotations

import sys

from .core.control import CONTROLLERS, make_controller
from .core.errors import ParameterError
from .dashboard import check_run_args, run_dashboard
from .pipeline import Lane

LANE = "camera"


def run(args, out=...) -> dict:
    out = sys.stdout if out is ... else out
    check_run_args(args)  # before anything is opened or truncated
    from .drivers.davis import open_camera

    if args.controller not in CONTROLLERS:
        raise ParameterError(f"unknown controller {args.controller!r}; available: {', '.join(sorted(CONTROLLERS))}")
    if args.duration is not None and not (0 < args.duration <= 24 * 3600):
        raise ParameterError(f"--duration must be a positive number of seconds, got {args.duration}")
    faults = None
    if args.device == "emulated" and args.emulate_unplug is not None:
        from .drivers.davis.emulator import Faults

        if not args.emulate_unplug > 0:
            raise ParameterError(f"--emulate-unplug must be a positive number of seconds, got {args.emulate_unplug}")
        faults = Faults(unplug_after_s=args.emulate_unplug)
    camera = open_camera(args.device, args.serial, scenario=args.scenario, seed=args.seed,
                         duration_s=args.duration if args.device == "emulated" else None,
                         reconnect=args.reconnect, faults=faults)
    info = camera.info
    limits = camera.limits
    sensor = camera.sensor

    def factory(name: str, old):
        return make_controller(name, sensor=sensor, limits=old.limits, exposure_us=old.exposure_us, gain=old.gain)

    ctrl = make_controller(args.controller, sensor=sensor, limits=limits)
    lane = Lane.build(LANE, ctrl, sensor)
    props = {"command": "live", "device": args.device, "serial": info.get("serial"),
             "firmware": info.get("firmware"), "logic": info.get("logic_version", info.get("logic")),
             "controller": args.controller, "camera_limits": limits, "camera_profile": "default DAVIS346 response",
             **({"scenario": args.scenario} if args.device == "emulated" else {})}
    recorder = None
    if args.record:
        from .drivers.replay import Recorder

        recorder = Recorder(args.record, sensor=sensor, properties={k: str(v) for k, v in props.items()})
    print(f"  live: {sensor.name or 'DAVIS'} {info.get('serial', '')} ({args.device}), {args.controller} drives "
          f"the exposure ({limits.exposure_min_us:g}..{limits.exposure_max_us:g} µs, digital gain ≤ "
          f"{limits.gain_max:g})", file=out)
    try:
        return run_dashboard(args, "live", camera, [lane], "live", props, f"necviz live: {info.get('serial', '')}",
                             sensor, recorder=recorder, controller_factory=factory, out=out,
                             expected_duration_s=args.duration, stop_after_s=args.duration)
    finally:
        if args.record:
            print(f"  recorded to {args.record} (replay it with: necviz replay {args.record})", file=out)
