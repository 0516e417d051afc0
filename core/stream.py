"""Stream packets: what they are, how a consumer receives them, and the order a live source sends them in.

A source delivers, in time order: event batches (:class:`~necviz.core.events.EventBatch`), an
exposure-start marker when an exposure begins, an exposure-end marker when it ends, the frame some
time after its end (readout), and optionally IMU and trigger batches (:data:`Packet`).

:func:`dispatch` hands one packet to the method of a :class:`PacketHandler` for its kind; it is the
one place that tells packets apart (controllers and P-TEDI are handlers). :func:`interleave`
produces the live order from arrays, for offline runs, tests and benchmarks.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from itertools import pairwise

import numpy as np

from necviz.core.errors import StreamError
from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch

#: What a source yields. Consumers that do not use IMU samples or triggers skip them.
Packet = EventBatch | ExposureMarker | Frame | ImuBatch | TriggerBatch


class PacketHandler:
    """Something that receives stream packets by kind; :func:`dispatch` calls the method for each.

    Every method returns what the handler makes of the packet (a controller: an exposure command
    or ``None``); the defaults ignore the packet.
    """

    def on_events(self, events: np.ndarray):
        """An event batch (:data:`~necviz.core.events.EVENT_DTYPE`, time-ordered)."""

    def on_exposure_start(self, t_us: int):
        """An exposure starts at ``t_us``."""

    def on_exposure_end(self, t_us: int):
        """The open exposure ends at ``t_us``."""

    def on_frame(self, frame: Frame):
        """A frame arrived (after its exposure ended)."""

    def on_imu(self, batch: ImuBatch):
        """IMU samples."""

    def on_triggers(self, batch: TriggerBatch):
        """External trigger edges."""


def dispatch(handler: PacketHandler, packet: Packet):
    """Call ``handler``'s method for ``packet``'s kind and return what it returns.

    Raises
    ------
    StreamError
        ``packet`` is none of the kinds of :data:`Packet`.
    """
    match packet:
        case EventBatch():
            return handler.on_events(packet.events)
        case ExposureMarker(kind="start"):
            return handler.on_exposure_start(packet.t_us)
        case ExposureMarker():
            return handler.on_exposure_end(packet.t_us)
        case Frame():
            return handler.on_frame(packet)
        case ImuBatch():
            return handler.on_imu(packet)
        case TriggerBatch():
            return handler.on_triggers(packet)
    raise StreamError(f"unknown packet type {type(packet).__name__}")


def packet_time_us(packet: Packet) -> int | None:
    """Sensor time a packet completes at (events: the last event; a frame: its exposure end)."""
    match packet:
        case EventBatch():
            return packet.t_last_us
        case ExposureMarker():
            return int(packet.t_us)
        case Frame():
            return int(packet.exposure_end_us)
        case ImuBatch():
            return int(packet.samples["t"][-1]) if len(packet) else None
        case TriggerBatch():
            return int(packet.triggers["t"][-1]) if len(packet) else None
    return None


def interleave(
    events: np.ndarray,
    frames: Sequence[Frame],
    frame_delay_us: int = 0,
    batch_us: int | None = None,
) -> Iterator[Packet]:
    """Yield event batches, exposure markers and frames in stream order.

    Events at exactly a marker's time follow the marker. A frame is delivered
    ``frame_delay_us`` after its exposure end (after the events before that time).
    ``batch_us`` additionally splits event batches at multiples of that period (as a live
    source delivering every ``batch_us``). Exposures must not overlap.
    """
    frames = sorted(frames, key=lambda f: f.exposure_start_us)
    for a, b in pairwise(frames):
        if b.exposure_start_us < a.exposure_end_us:
            raise StreamError(f"exposures of frames {a.sequence} and {b.sequence} overlap")
    # (time, order, packet): order puts markers before the frame delivered at the same time
    cuts: list[tuple[int, int, Packet | None]] = []
    for f in frames:
        cuts.append((int(f.exposure_start_us), 0, ExposureMarker(int(f.exposure_start_us), "start")))
        cuts.append((int(f.exposure_end_us), 1, ExposureMarker(int(f.exposure_end_us), "end")))
        cuts.append((int(f.exposure_end_us) + int(frame_delay_us), 2, f))
    if batch_us:
        if events.size:
            t0, t1 = int(events["t"][0]), int(events["t"][-1])
            for tb in range((t0 // batch_us + 1) * batch_us, t1 + 1, batch_us):
                cuts.append((tb, -1, None))
    cuts.sort(key=lambda c: (c[0], c[1]))
    # one search for all cut times, on a contiguous copy (searching a strided field view copies it per call)
    ends = np.searchsorted(np.ascontiguousarray(events["t"]), np.array([c[0] for c in cuts], np.int64), side="left")
    pos = 0
    for end, (_, _, packet) in zip(ends.tolist(), cuts, strict=True):
        if end > pos:
            yield EventBatch(events[pos:end])
            pos = end
        if packet is not None:
            yield packet
    if pos < events.size:
        yield EventBatch(events[pos:])
