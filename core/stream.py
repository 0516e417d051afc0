"""Stream order: interleave recorded events and frames into the packets a live source yields.

A live source delivers, in time order: event batches, an exposure-start marker when an
exposure begins, an exposure-end marker when it ends, and the frame some time after its end
(readout). :func:`interleave` produces exactly that order from arrays, for offline runs,
tests and benchmarks.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from necviz.core.errors import StreamError
from necviz.core.frames import ExposureMarker, Frame


def interleave(
    events: np.ndarray,
    frames: Sequence[Frame],
    frame_delay_us: int = 0,
    batch_us: int | None = None,
) -> Iterator[np.ndarray | ExposureMarker | Frame]:
    """Yield event batches, exposure markers and frames in stream order.

    Events at exactly a marker's time follow the marker. A frame is delivered
    ``frame_delay_us`` after its exposure end (after the events before that time).
    ``batch_us`` additionally splits event batches at multiples of that period (as a live
    source delivering every ``batch_us``). Exposures must not overlap.
    """
    frames = sorted(frames, key=lambda f: f.exposure_start_us)
    for a, b in zip(frames, frames[1:]):
        if b.exposure_start_us < a.exposure_end_us:
            raise StreamError(f"exposures of frames {a.sequence} and {b.sequence} overlap")
    # (time, order, packet): order puts markers before the frame delivered at the same time
    cuts: list[tuple[int, int, object]] = []
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
    for end, (_, _, packet) in zip(ends.tolist(), cuts):
        if end > pos:
            yield events[pos:end]
            pos = end
        if packet is not None:
            yield packet
    if pos < events.size:
        yield events[pos:]
