"""Output folders are created when missing (parents too), said in one line; a file in the way is one line."""

from __future__ import annotations

import pytest

from necviz.commands.cli import main
from necviz.core.errors import ParameterError
from necviz.options import ClipOptions
from necviz.outputs import check_output

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


def test_a_missing_output_folder_is_created_and_said(tmp_path, capsys):
    out = tmp_path / "out" / "deep" / "x.json"
    assert check_output(out, "--json") == out
    assert out.parent.is_dir()
    said = capsys.readouterr().out.splitlines()
    assert said == [f"  created folder {str(out.parent)!r} for --json"]


def test_the_clips_folder_is_created_and_a_file_in_the_way_is_refused(tmp_path, capsys):
    ClipOptions(tmp_path / "clips" / "a").check()
    assert (tmp_path / "clips" / "a").is_dir()
    assert "created folder" in capsys.readouterr().out
    (tmp_path / "f").write_text("x")
    with pytest.raises(ParameterError, match="is a file, not a folder"):
        ClipOptions(tmp_path / "f").check()


def test_clip_bounds_without_clips_are_refused(tmp_path, capsys):
    assert main(["demo", "--clip-before", "2", "--save", str(tmp_path / "x.rrd"), "--no-prompt"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["necviz: error: --clip-before sets the flight recorder: it needs --clips DIR"]
    assert not (tmp_path / "x.rrd").exists()


def test_a_sweep_out_folder_gets_its_parents(tmp_path, capsys):
    from necviz.sweeps.store import prepare_out

    prepare_out(tmp_path / "out" / "example", resume=False, force=False)
    assert (tmp_path / "out").is_dir()
    assert "created folder" in capsys.readouterr().out
