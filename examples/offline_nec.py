#!/usr/bin/env python
"""NEC on a synthetic lighting step: what P-TEDI predicted and what NEC commanded, frame by frame.

A textured 346x260 scene brightens by ``--step`` ln units (default 3.0, about 26 dB) at 45 ms.
Every pixel emits ideal ON events at that moment; frames are exposed with the exposure NEC
commanded before they started. Compare the over-exposed fraction of each frame with what the
pre-step exposure would have given (``stale``): NEC adjusts before the first bright frame.

usage: python examples/offline_nec.py [--step 3.0]
"""

import argparse
import math

import numpy as np

from necviz.core import DAVIS346, EVENT_DTYPE, Frame, PeripheralEstimator, TediParams, default_davis346
from necviz.core.control import CameraLimits, NECController
from necviz.core.stream import interleave

C_ON = 0.26


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, default=3.0, help="brightening in natural-log units (> 0)")
    args = ap.parse_args()
    if not args.step > 0:
        ap.error("--step must be positive")
    crf = default_davis346()
    rng = np.random.default_rng(0)
    h, w = DAVIS346.shape
    log_l0 = 5.0 + 0.4 * rng.standard_normal((h, w))  # textured scene, ln irradiance
    step_t = 45_000

    # ideal events: each pixel crosses floor((step + phase) / c) thresholds at the step
    phase = rng.uniform(0, C_ON, (h, w))
    n = np.floor((args.step + phase) / C_ON).astype(int)
    ys, xs = np.nonzero(n)
    counts = n[ys, xs]
    ev = np.zeros(counts.sum(), EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = step_t, np.repeat(xs, counts), np.repeat(ys, counts), 1

    def expose(s, t_us, gain):
        """Exact frame: exposure average of the step scene through the camera response."""
        bright = max(0, s + t_us - max(s, step_t)) / t_us
        mean_l = np.exp(log_l0) * ((1 - bright) + bright * math.exp(args.step))
        z = crf.intensity(np.log(mean_l) + math.log(t_us / 1e6) + math.log(gain))
        return np.clip(np.rint(z), 0, 255).astype(np.uint8)

    nec = NECController(
        PeripheralEstimator(DAVIS346, TediParams(C_ON, 0.24), crf),
        CameraLimits(10, 20_000, 4.0),
        exposure_us=math.exp(crf.goal_log_exposure - 5.0) * 1e6,
    )
    exposure, gain, first = nec.exposure_us, nec.gain, nec.exposure_us
    print(f"{'frame':>5s} {'start ms':>8s} {'exposure µs':>11s} {'gain':>5s} {'over-exposed':>12s} {'stale':>6s}  ln P")
    done = 0
    for i in range(6):
        s = 1_000 + 20_000 * i
        for pk in interleave(ev[(ev["t"] >= done) & (ev["t"] < s)], []):
            if (cmd := nec.feed(pk)) is not None:
                exposure, gain = cmd.exposure_us, cmd.gain
        f = Frame(expose(s, round(exposure), gain), s, s + round(exposure), gain, i)
        for pk in interleave(ev[(ev["t"] >= s) & (ev["t"] < f.exposure_end_us)], [f]):
            if (cmd := nec.feed(pk)) is not None:
                exposure, gain = cmd.exposure_us, cmd.gain
        done = f.exposure_end_us
        stale = (expose(s, round(first), 1.0) >= 250).mean()
        print(
            f"{i:5d} {s / 1000:8.1f} {f.exposure_us:11d} {gain:5.2f} {(f.image >= 250).mean():12.1%} "
            f"{stale:6.1%}  {nec.last_log_irradiance:.3f}"
        )


if __name__ == "__main__":
    main()
