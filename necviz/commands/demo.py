"""``necviz demo``: the embedded default — a simulated ``tunnel_exit``, NEC against the baselines.

Every controller drives its own simulated camera; all cameras share one scene and one event
stream (:class:`~necviz.drivers.sim.rig.SimRig`), as in ``necviz compare``, shown side by side
in the ``compare`` layout. No hardware and no files needed. The rendered scene and its events are kept in
the scene cache (:mod:`necviz.drivers.sim.scene_cache`), so running the same demo again skips the
rendering (the packets are the same). From Python::

    import necviz
    necviz.run_demo(necviz.DemoOptions(necviz.SceneOptions("indoor_outdoor")),
                    necviz.ViewerOptions(save="demo.rrd"))
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from necviz.commands import Command
from necviz.commands.args import (
    add_clip_args,
    add_scene_args,
    add_show_args,
    add_video_args,
    clip_options,
    controller_choices,
    controller_list,
    scene_options,
    show_options,
    tune_options,
    video_options,
)
from necviz.progress import output

if TYPE_CHECKING:
    from necviz.options import DemoOptions, ViewerOptions


def run(options: DemoOptions | None = None, viewer: ViewerOptions | None = None, out=..., stdin=None) -> dict:
    """Run the demo: every controller drives its own simulated camera through one scene, side by side.

    Parameters
    ----------
    options : DemoOptions, optional
        The scene, the controllers, recordings, clips, video (default: ``DemoOptions()``).
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
    ParameterError
        Bad options or output files (an output that exists without ``force``, or is an input).
    """
    from necviz.dashboard import session as dashboard
    from necviz.dashboard.session import Session, lane_labels
    from necviz.dashboard.viewer import resolve
    from necviz.drivers.sim.scene_cache import SceneCache
    from necviz.layouts import make_blueprint
    from necviz.options import DemoOptions, ViewerOptions
    from necviz.profiles import load_profile
    from necviz.runs import build_rig

    out = output(out)
    options = options or DemoOptions()
    viewer = resolve(viewer or ViewerOptions(), "demo")  # the headless default filled in
    sc = options.scene
    scene = sc.build()  # a bad scene parameter is refused before any file is looked at
    options.check_outputs(viewer)  # before anything starts
    profile = load_profile(options.profile) if options.profile is not None else None
    show = options.show
    observers = []  # the command's own: the video writer, the flight recorder (made when the run starts)
    if options.video is not None:  # only files: the run goes as fast as it can, the video keeps its own pace
        from necviz.dashboard.video import plan, video_observer

        show, video_options = plan(show, options.video, viewer)
        observers.append(video_observer(video_options))
    if options.clips is not None:
        from necviz.dashboard.flight_recorder import clip_observer

        options.clips.check()
        observers.insert(0, clip_observer(options.clips))
    # a demo is replayed: its scene and events come from the scene cache from the second run on
    scene, rig, lanes, limits = build_rig(scene, options.controllers, profile, cache=SceneCache.default())
    props = {
        "command": "demo",
        "scenario": sc.name,
        "seed": sc.resolved_seed,
        "duration_s": scene.duration_us / 1e6,
        "scenario_params": sc.params,
        "controllers": ",".join(options.controllers),
        "camera_limits": limits,
        "camera_profile": str(options.profile) if options.profile else "default DAVIS346 response",
    }
    print(f"  demo: {sc.name}, {', '.join(ln.name for ln in lanes)} ({props['duration_s']:g} s simulated)", file=out)
    layout = viewer.layout or "compare"
    blueprint = make_blueprint(
        layout, [ln.name for ln in lanes], rig.sensor.width, rig.sensor.height, lane_labels(lanes)
    )
    return dashboard.run(
        rig,
        lanes,
        viewer,
        blueprint,
        Session(
            command="demo",
            layout=layout,
            title=f"necviz demo: {sc.name}",
            properties=props,
            show=show,
            tune=options.tune,
            record=options.record,
            record_properties={**props, "recorded_lane": lanes[0].name},
            record_camera=lanes[0].camera or lanes[0].name,
            lossless=True,
            expected_duration_s=props["duration_s"],
            observers=observers,
        ),
        out,
        stdin,
    )


def add_arguments(p) -> None:
    from necviz.names import DEFAULT_CONTROLLERS

    add_scene_args(p)
    p.add_argument(
        "--controllers",
        type=controller_list,
        default=",".join(DEFAULT_CONTROLLERS),
        help=f"comma-separated, from {', '.join(controller_choices())} (default: {', '.join(DEFAULT_CONTROLLERS)})",
    )
    p.add_argument(
        "--record",
        metavar="FILE.necrec",
        help="also record the first controller's camera (events, frames, commands) to a crash-safe native file",
    )
    add_show_args(p)
    add_clip_args(p)
    add_video_args(p)


def _command(args) -> int:
    from necviz.dashboard.viewer_flags import viewer_options
    from necviz.options import DemoOptions

    run(
        DemoOptions(
            scene_options(args),
            args.controllers,
            record=args.record,
            force=args.force,
            profile=args.profile,
            show=show_options(args),
            tune=tune_options(args),
            clips=clip_options(args),
            video=video_options(args),
        ),
        viewer_options(args),
    )
    return 0


COMMAND = Command(
    name="demo",
    help="the dashboard on the simulator: tunnel_exit, NEC versus the baselines side by side",
    description="A simulated scene (tunnel_exit by default), every controller driving its own "
    "camera, shown in the compare layout. No hardware or files needed.",
    add_arguments=add_arguments,
    run=_command,
)
