"""interleave() yields packets in the order a live source would."""

import numpy as np
import pytest

from necviz.core.errors import StreamError
from necviz.core.events import EventBatch, make_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import PacketHandler, dispatch, interleave, packet_time_us


def _frame(s, e, seq=0):
    return Frame(np.full((2, 2), 100, np.uint8), s, e, 1.0, seq)


def test_order_markers_frames_and_events():
    ev = make_events([5, 10, 10, 20, 30, 31], [0] * 6, [0] * 6, [1] * 6)
    f = _frame(10, 30)
    out = list(interleave(ev, [f], frame_delay_us=1))
    kinds = [
        ("ev", p.events["t"].tolist())
        if isinstance(p, EventBatch)
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
    assert sum(len(p) for p in out if isinstance(p, EventBatch)) == ev.size


def test_batch_period_splits_events():
    ev = make_events(np.arange(0, 5000, 10), np.zeros(500), np.zeros(500), np.ones(500))
    batches = [p.events for p in interleave(ev, [], batch_us=1000)]
    assert [int(b["t"][0]) for b in batches] == [0, 1000, 2000, 3000, 4000]
    assert all(int(b["t"][-1]) < int(b["t"][0]) + 1000 for b in batches)


def test_overlapping_exposures_rejected():
    with pytest.raises(StreamError, match="overlap"):
        list(interleave(make_events([], [], [], []), [_frame(0, 20), _frame(10, 30, 1)]))


def test_empty_batches_are_harmless():
    est = PeripheralEstimator(SensorGeometry(2, 2))
    est.update(make_events([], [], [], []))
    assert est.last_event_us < 0 and est.counts_on.sum() == 0


class _Log(PacketHandler):
    """Records which method dispatch called, with what; returns a tag so the return value is checked too."""

    def __init__(self):
        self.calls = []

    def on_events(self, events):
        self.calls.append(("events", events["t"].tolist()))
        return "E"

    def on_exposure_start(self, t_us):
        self.calls.append(("start", t_us))
        return "S"

    def on_exposure_end(self, t_us):
        self.calls.append(("end", t_us))
        return "N"

    def on_frame(self, frame):
        self.calls.append(("frame", frame.sequence))
        return "F"

    def on_imu(self, batch):
        self.calls.append(("imu", len(batch)))
        return "I"

    def on_triggers(self, batch):
        self.calls.append(("triggers", len(batch)))
        return "T"


def _imu(ts):
    s = np.zeros(len(ts), IMU_DTYPE)
    s["t"] = ts
    return ImuBatch(s)


def _triggers(ts):
    s = np.zeros(len(ts), TRIGGER_DTYPE)
    s["t"] = ts
    return TriggerBatch(s)


def test_dispatch_calls_the_method_for_each_kind_and_returns_its_answer():
    packets = [
        EventBatch(make_events([3, 4], [0, 0], [0, 0], [1, -1])),
        ExposureMarker(10, "start"),
        ExposureMarker(30, "end"),
        _frame(10, 30, seq=7),
        _imu([40, 41, 42]),
        _triggers([50]),
    ]
    h = _Log()
    assert [dispatch(h, p) for p in packets] == ["E", "S", "N", "F", "I", "T"]
    assert h.calls == [
        ("events", [3, 4]),
        ("start", 10),
        ("end", 30),
        ("frame", 7),
        ("imu", 3),
        ("triggers", 1),
    ]
    # the defaults ignore every kind
    assert [dispatch(PacketHandler(), p) for p in packets] == [None] * 6


def test_dispatch_rejects_what_is_not_a_packet():
    # a bare event array is no longer a packet: it must be wrapped, never silently ignored
    for bad in (make_events([1], [0], [0], [1]), "events", None):
        with pytest.raises(StreamError, match="unknown packet type"):
            dispatch(_Log(), bad)


def test_packet_time_is_when_the_packet_completes():
    ev = make_events([5, 9, 12], [0] * 3, [0] * 3, [1] * 3)
    batch = EventBatch(ev)
    assert len(batch) == 3 and batch.t_last_us == 12
    assert packet_time_us(batch) == 12
    assert packet_time_us(EventBatch(ev[:0])) is None and EventBatch(ev[:0]).t_last_us is None
    assert packet_time_us(ExposureMarker(20, "end")) == 20
    assert packet_time_us(_frame(10, 30)) == 30
    assert packet_time_us(_imu([1, 2, 8])) == 8
    assert packet_time_us(_triggers([4])) == 4
    assert packet_time_us(_imu([])) is None
