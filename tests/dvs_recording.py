"""A NEC run on a simulated rig, recorded to a ``.necrec`` while its DVS settings change mid-run.

Shared by ``test_dvs_controls.py`` and ``test_calibrate_bias_settings.py``: both need a recording whose
bias settings changed live (``Pipeline.tune_dvs``), as ``necviz live`` writes one, to check what reads it back.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from necviz.core.sensor import SensorGeometry


def nec_pipeline(rig, sensor: SensorGeometry):
    """One NEC lane on ``rig``'s ``camera``, no warm-up (the tests' rigs are small)."""
    from necviz.pipeline import Lane, Pipeline
    from necviz.runs import make_controller

    lane = Lane("camera", make_controller("nec", sensor=sensor, limits=rig.camera_info.limits))
    return Pipeline(rig, [lane], warm_up=False)


def record_with_dvs_changes(
    pipe,
    path: Path,
    sensor: SensorGeometry,
    changes: Sequence[tuple[str, float]],
    when: Callable[[int, object], bool],
):
    """Run ``pipe`` to its end, recording ``camera`` to ``path``; at the first event batch for which
    ``when(batch_number, batch)`` holds (numbered from 1), apply every ``(key, value)`` of ``changes`` with
    ``pipe.tune_dvs``. Returns the finished pipeline (``pipe.dvs`` tells where P-TEDI followed)."""
    from necviz.drivers.recordings import Recorder
    from necviz.pipeline import Observer, RecorderObserver

    state = {"n": 0, "done": False}

    class Change(Observer):
        def events(self, batch):
            state["n"] += 1
            if not state["done"] and when(state["n"], batch):
                state["done"] = True
                for key, value in changes:
                    pipe.tune_dvs(key, value)

    pipe.observers += [RecorderObserver(Recorder(path, sensor=sensor, properties={}), "camera"), Change()]
    pipe.run().finish()
    return pipe
