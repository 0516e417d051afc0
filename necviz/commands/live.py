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

from necviz.core.control import make_controller
from necviz.core.errors import ParameterError
from necviz.dashboard import session as dashboard
from necviz.dashboard.flight_recorder import clip_observer
from necviz.dashboard.recorders import open_recorder
from necviz.dashboard.session import Session, preflight, scene_inputs
from necviz.layouts import make_blueprint
from necviz.options import LiveOptions, ViewerOptions
from necviz.pipeline import Lane
from necviz.progress import output

LANE = "camera"


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
    viewer, profile = preflight(
        "live",
        viewer,
        {"--record": options.record},
        options.force,
        inputs=scene_inputs(options.scene, options.tune),
        profile=options.profile,
    )  # before the camera is opened
    if options.clips is not None:
        options.clips.check()
    if viewer.save is not None:  # a long session's file grows by GB an hour: say so before it fills a disk
        from necviz.dashboard.rrd_file import size_warning

        note = size_warning(viewer.save, options.duration_s, options.show.image_rate_hz)
        if note is not None and out is not None:
            print(note, file=out)
    from necviz.drivers.davis import CameraOptions, open_camera

    backend = None
    if options.device == "emulated":
        from necviz.drivers.davis.emulator import EmulatedDavis346, EmulatorOptions, Faults

        spec = options.scene.spec()
        faults = Faults(unplug_after_s=options.emulate_unplug_s) if options.emulate_unplug_s is not None else None
        emulated = EmulatorOptions(
            scenario=spec["name"],
            seed=options.scene.resolved_seed,
            duration_s=options.duration_s,
            scenario_params={**spec["params"], **options.scene.params},
        )
        backend = EmulatedDavis346(emulated, faults)
    if options.device == "dv":
        from necviz.drivers.dv_camera import open_dv_camera

        if options.reconnect:
            raise ParameterError("--reconnect works with necviz's driver (--device usb), not with --device dv")

        camera = open_dv_camera(options.serial, options=CameraOptions())
    else:
        camera = open_camera(
            options.device, options.serial, options=CameraOptions(reconnect=options.reconnect), backend=backend
        )
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
    recorder = None
    try:
        if options.record is not None:  # a camera session cannot be recorded again: kept if it fails
            recorder = open_recorder(options.record, sensor, props, keep_partial=True)
    except BaseException:
        camera.close()
        raise
    print(
        f"  live: {sensor.name or 'DAVIS'} {info.get('serial', '')} ({options.device}), {options.controller} drives "
        f"the exposure ({limits.exposure_min_us:g}..{limits.exposure_max_us:g} µs, digital gain ≤ "
        f"{limits.gain_max:g})",
        file=out,
    )
    layout = viewer.layout or "live"
    settings = Session(
        command="live",
        layout=layout,
        title=f"necviz live: {info.get('serial', '')}",
        properties=props,
        show=options.show,
        tune=options.tune,
        recorder=recorder,
        record_camera=LANE,
        lossless=False,
        history=options.history,
        expected_duration_s=options.duration_s,
        stop_after_s=options.duration_s,
        keep_partial=True,
        observers=[clip_observer(options.clips)] if options.clips is not None else [],
    )
    blueprint = make_blueprint(layout, [LANE], sensor.width, sensor.height)
    return dashboard.run(camera, [lane], viewer, blueprint, settings, out, stdin)
