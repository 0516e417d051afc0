#!/usr/bin/env python
"""P-TEDI on a real recording: per frame, the event-propagated prediction vs what the frame measured.

Opens a recording with ``necviz.drivers.recordings.open_recording`` (any supported format: a DAVIS
recording of your own, or one made without a camera by
``necviz live --device emulated --duration 2 --record run.necrec``) and feeds every packet, in stream order, to a
whole-sensor ``PeripheralEstimator``. At each exposure start it records the prediction
``ln P(s)`` propagated with events from the previous frame's anchor; when the frame arrives it
prints that prediction beside the frame's own estimate of ``ln P(s)`` (Eq. 14/15: image mean
through the camera response, minus ln T, corrected for the events during the exposure).

usage: python examples/replay_summary.py RECORDING [--c-on 0.26] [--c-off 0.24]
"""

import argparse
import math
import sys
from pathlib import Path

from necviz.core import EventBatch, ExposureMarker, NecvizError, PeripheralEstimator, TediParams
from necviz.drivers.recordings import open_recording


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "recording",
        help="a recorded file (AEDAT, native, ROS bag, ...); make one with "
        "necviz live --device emulated --duration 2 --record run.necrec",
    )
    ap.add_argument("--c-on", type=float, default=0.26, help="ON contrast threshold, ln units")
    ap.add_argument("--c-off", type=float, default=0.24, help="OFF contrast threshold, ln units")
    args = ap.parse_args()
    if not Path(args.recording).is_file():
        print(
            f"replay_summary: recording {args.recording} not found; pass the path of an AEDAT/native/bag file",
            file=sys.stderr,
        )
        return 1
    try:
        rec = open_recording(args.recording)
        est = PeripheralEstimator(rec.sensor, TediParams(args.c_on, args.c_off))
        print(f"{args.recording}: {rec.format}, {rec.sensor.width}x{rec.sensor.height}, exposure {rec.exposure_source}")
        print(
            f"{'frame':>5s} {'start ms':>8s} {'exposure µs':>11s} {'events':>7s} {'predicted ln P':>14s} "
            f"{'frame ln P':>10s} {'diff':>7s} {'valid':>6s}"
        )
        t0_us, predicted, events = None, math.nan, 0
        for packet in rec:
            fe = est.feed(packet)  # events, exposure markers and frames; IMU samples and triggers are ignored
            if isinstance(packet, EventBatch):
                events += len(packet)
            elif isinstance(packet, ExposureMarker) and packet.kind == "start":
                t0_us = packet.t_us if t0_us is None else t0_us
                predicted = est.predict(packet.t_us) if est.ready else math.nan  # before this frame anchors
            elif fe is not None:
                measured = float(fe.log_anchor[0])
                pred, diff = (
                    (f"{predicted:.3f}", f"{predicted - measured:+.3f}")
                    if math.isfinite(predicted)
                    else ("— (first)", "—")
                )
                print(
                    f"{fe.sequence:5d} {(fe.exposure_start_us - t0_us) / 1e3:8.1f} {packet.exposure_us:11d} "
                    f"{events:7d} {pred:>14s} {measured:10.3f} {diff:>7s} {fe.valid_fraction[0]:6.1%}"
                )
                events = 0
    except NecvizError as e:  # unreadable or damaged file, bad thresholds: one line, no traceback
        print(f"replay_summary: {e}", file=sys.stderr)
        return 1
    print(
        f"{est.frames_seen} frames ({est.frames_skipped} not used as anchors); final prediction "
        f"ln P = {est.predict():.3f}"
        if est.ready
        else "no usable frame: nothing to anchor P-TEDI"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
