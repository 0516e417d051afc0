"""interleave() yields packets in the order a live source would."""

import numpy as np
import pytest

from necviz.core.errors import StreamError
from necviz.core.events import make_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import interleave


def _frame(s, e, seq=0):
    return Frame(np.full((2, 2), 100, np.uint8), s, e, 1.0, seq)


def test_order_markers_frames_and_events():
    ev = make_events([5, 10, 10, 20, 30, 31], [0] * 6, [0] * 6, [1] * 6)
    f = _frame(10, 30)
    out = list(interleave(ev, [f], frame_delay_us=1))
    kinds = [
        ("ev", p["t"].tolist())
        if isinstance(p, np.ndarray)
        else (p.kind, p.t_us)
        if isinstance(p, ExposureMarker)
        else ("frame", p.sequence)
        for p in out
    ]
    # events at exactly the start follow the start marker; those at the end follow the end marker;
    # the frame arrives frame_delay_us after the end, after the events before that time
    assert kinds == [
        ("ev", [5]),
        ("start", 10),
        ("ev", [10, 10, 20]),
        ("end", 30),
        ("ev", [30]),
        ("frame", 0),
        ("ev", [31]),
    ]
    assert sum(p.size for p in out if isinstance(p, np.ndarray)) == ev.size


def test_batch_period_splits_events():
    ev = make_events(np.arange(0, 5000, 10), np.zeros(500), np.zeros(500), np.ones(500))
    batches = [p for p in interleave(ev, [], batch_us=1000)]
    assert [int(b["t"][0]) for b in batches] == [0, 1000, 2000, 3000, 4000]
    assert all(int(b["t"][-1]) < int(b["t"][0]) + 1000 for b in batches)


def test_overlapping_exposures_rejected():
    with pytest.raises(StreamError, match="overlap"):
        list(interleave(make_events([], [], [], []), [_frame(0, 20), _frame(10, 30, 1)]))


def test_empty_batches_are_harmless():
    est = PeripheralEstimator(SensorGeometry(2, 2))
    est.update(make_events([], [], [], []))
    assert est.last_event_us < 0 and est.counts_on.sum() == 0
