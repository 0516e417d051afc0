"""Option objects refuse nonsense naming their field; the command line names the flag instead.

Every option class of :mod:`necviz.options` raises an :class:`~necviz.core.errors.OptionError` whose
``field`` (``"ClipOptions.before_s"``) the message names; ``necviz`` prints the flag that sets it
(:data:`necviz.flags.FIELD_FLAGS`) in one line, exit code 2, no traceback.
"""

from __future__ import annotations

import pytest

from necviz.commands.cli import main
from necviz.core.errors import OptionError, ParameterError
from necviz.flags import FIELD_FLAGS, in_flag_terms
from necviz.options import (
    ClipOptions,
    CompareOptions,
    DemoOptions,
    ExportOptions,
    LiveOptions,
    ReplayOptions,
    SceneOptions,
    ShowOptions,
    TuneOptions,
    VideoOptions,
    ViewerOptions,
)

NONSENSE = [
    (lambda: SceneOptions("moon"), "SceneOptions.scenario"),
    (lambda: SceneOptions(seed=-1), "SceneOptions.seed"),
    (lambda: SceneOptions(duration_s=float("nan")), "SceneOptions.duration_s"),
    (lambda: ViewerOptions(layout="nope"), "ViewerOptions.layout"),
    (lambda: ViewerOptions(grpc_port=0), "ViewerOptions.grpc_port"),
    (lambda: ViewerOptions(memory_limit="banana"), "ViewerOptions.memory_limit"),
    (lambda: ViewerOptions(notebook=True, save="x.rrd"), "ViewerOptions.notebook"),
    (lambda: ShowOptions("zero"), "ShowOptions.speed"),
    (lambda: ShowOptions(event_window_ms=-1), "ShowOptions.event_window_ms"),
    (lambda: ShowOptions(event_points=1.5), "ShowOptions.event_points"),
    (lambda: TuneOptions(dvs=(("c_on", "banana"),)), "TuneOptions.dvs"),
    (lambda: ClipOptions(""), "ClipOptions.folder"),
    (lambda: ClipOptions("clips", before_s=-1), "ClipOptions.before_s"),
    (lambda: ClipOptions("clips", memory_mb=0), "ClipOptions.memory_mb"),
    (lambda: VideoOptions(""), "VideoOptions.path"),
    (lambda: VideoOptions("v.mp4", speed="max"), "VideoOptions.speed"),
    (lambda: VideoOptions("v.mp4", fps=0), "VideoOptions.fps"),
    (lambda: DemoOptions(controllers=("nope",)), "DemoOptions.controllers"),
    (lambda: DemoOptions(controllers=("nec", "nec")), "DemoOptions.controllers"),
    (lambda: ReplayOptions(""), "ReplayOptions.file"),
    (lambda: ReplayOptions("r.aedat4", controller="nope"), "ReplayOptions.controller"),
    (lambda: ReplayOptions("r.aedat4", start_s=2.0, end_s=1.0), "ReplayOptions.end_s"),
    (lambda: ReplayOptions("r.aedat4", exposure_us=0), "ReplayOptions.exposure_us"),
    (lambda: ExportOptions("in.aedat4", ""), "ExportOptions.out_path"),
    (lambda: ExportOptions("in.aedat4", "out.h5", compression="zip"), "ExportOptions.compression"),
    (lambda: ExportOptions("in.aedat4", "out.h5", pipe_timeout_s=-1), "ExportOptions.pipe_timeout_s"),
    (lambda: LiveOptions("firewire"), "LiveOptions.device"),
    (lambda: LiveOptions(duration_s=0), "LiveOptions.duration_s"),
    (lambda: LiveOptions(history=0), "LiveOptions.history"),
    (lambda: CompareOptions(seeds=0), "CompareOptions.seeds"),
    (lambda: CompareOptions(controller_params={"nosuch": {"goal": 1}}), "CompareOptions.controller_params"),
]


@pytest.mark.parametrize("make, field", NONSENSE, ids=[f for _, f in NONSENSE])
def test_an_option_object_refuses_nonsense_naming_its_field(make, field):
    with pytest.raises(OptionError) as info:
        make()
    e = info.value
    assert isinstance(e, ParameterError)  # what a caller catching the library's errors already catches
    assert e.field == field and field in str(e) and "\n" not in str(e)
    assert "--" not in str(e).replace("--dvs", "")  # the library's terms, not the command line's


def test_every_option_class_is_frozen_and_keyword_only_beyond_its_subject():
    import dataclasses

    for cls in (
        SceneOptions,
        ViewerOptions,
        ShowOptions,
        TuneOptions,
        ClipOptions,
        VideoOptions,
        DemoOptions,
        ReplayOptions,
        ExportOptions,
        LiveOptions,
        CompareOptions,
    ):
        params = cls.__dataclass_params__  # type: ignore[attr-defined]
        assert params.frozen, cls
        positional = [f.name for f in dataclasses.fields(cls) if not f.kw_only]
        assert len(positional) <= 2, (cls, positional)


def test_a_refused_field_reads_as_its_flag():
    e = OptionError("ReplayOptions.end_s", "ReplayOptions.end_s (1.0 s) must come after ReplayOptions.start_s (2.0 s)")
    assert in_flag_terms(e) == "--end (1.0 s) must come after --start (2.0 s)"
    assert all(flag.startswith("--") or flag.isupper() for flag in FIELD_FLAGS.values())


def _cli(argv, capsys) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err


CLI = [
    (["demo", "--scenario", "moon"], "--scenario: 'moon' is neither a preset"),
    (["demo", "--serve", "--grpc-port", "9100", "--web-port", "9100"], "--grpc-port and --web-port are both 9100"),
    (["demo", "--speed", "0"], "--speed must be 'max'"),
    (["demo", "--dvs", "c_on=banana"], "--dvs:"),
    (["demo", "--video", "v.mp4", "--video-fps", "0"], "--video-fps"),
    (["demo", "--controllers", "nec,nec"], "each controller may appear once in --controllers"),
    (["replay", "r.aedat4", "--start", "2", "--end", "1"], "--end (1.0 s) must come after --start (2.0 s)"),
    (["export", "in.aedat4", "out.h5", "--start", "2", "--end", "1"], "--end (1.0 s) must come after --start"),
    (["live", "--device", "emulated", "--duration", "0"], "--duration"),
    (["compare", "--param", "nosuch.goal=1"], "--param names nosuch, which is not among the controllers"),
]


@pytest.mark.parametrize("argv, says", CLI, ids=[" ".join(a[:2]) + " " + a[-1] for a, _ in CLI])
def test_the_command_line_names_the_flag_in_one_line(argv, says, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = _cli([*argv, "--save", str(tmp_path / "x.rrd")] if argv[0] == "demo" else argv, capsys)
    assert code == 2, err
    assert err.startswith("necviz: error: ") and err.count("\n") == 1, err
    assert says in err and "Traceback" not in err and "Options." not in err, err


def test_a_clip_folder_that_is_a_file_is_named_by_its_flag(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "f").write_text("")
    code, err = _cli(["demo", "--clips", str(tmp_path / "f"), "--save", str(tmp_path / "x.rrd")], capsys)
    assert code == 2 and err.count("\n") == 1 and "--clips" in err and "is a file, not a folder" in err, err
    assert "ClipOptions" not in err and not (tmp_path / "x.rrd").exists()
