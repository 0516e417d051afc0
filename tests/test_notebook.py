"""examples/notebook.ipynb runs headless (nbclient) and each run shows the Rerun viewer widget inline."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "notebook.ipynb"
WIDGET = "application/vnd.jupyter.widget-view+json"


def test_the_example_notebook_shows_the_viewer_for_a_demo_and_a_replay(tmp_path):
    pytest.importorskip("rerun_notebook", reason="the notebook extra is not installed (pip install 'necviz[notebook]')")
    nbformat = pytest.importorskip("nbformat", reason="nbformat comes with the notebook extra")
    nbclient = pytest.importorskip("nbclient", reason="nbclient comes with the notebook extra")
    pytest.importorskip("ipykernel", reason="ipykernel comes with the notebook extra")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    code = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors, errors
    runs = [c for c in code if "necviz.ViewerOptions(notebook=True)" in c.source]
    assert len(runs) == 2
    for cell in runs:
        shown = [o for o in cell.outputs if o.get("output_type") == "display_data" and WIDGET in o.get("data", {})]
        assert shown, f"no viewer widget in the output of:\n{cell.source}"
        text = "".join(o.get("text", "") for o in cell.outputs if o.get("output_type") == "stream")
        assert ("saturated frames" in text) or ("events replayed" in text)
    replay_text = "".join(o.get("text", "") for o in runs[1].outputs if o.get("output_type") == "stream")
    frames = int(replay_text.split(" frames")[0].split()[-1])
    assert frames > 0  # the replay read back what the demo recorded


def test_notebook_is_not_combined_with_other_viewers():
    from necviz import ViewerOptions
    from necviz.core.errors import ParameterError

    with pytest.raises(ParameterError, match="notebook"):
        ViewerOptions(notebook=True, save="x.rrd")
    assert ViewerOptions(notebook=True).watched


def test_notebook_outside_a_notebook_says_so_before_anything_runs(tmp_path, monkeypatch):
    import necviz
    from necviz.core.errors import ParameterError

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ParameterError, match="this is not a notebook"):
        necviz.run_demo(
            necviz.DemoOptions(necviz.SceneOptions("static_lab", duration_s=0.1), ("fixed",)),
            necviz.ViewerOptions(notebook=True),
        )
    assert list(tmp_path.iterdir()) == []
