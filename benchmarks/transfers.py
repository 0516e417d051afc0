#!/usr/bin/env python
"""USB transfers: how long data waits between being sensed and reaching the host, per reader, transfer size and rate.

The old reader kept one synchronous bulk read in flight (``CameraOptions(usb="single")``, 8, 64 and 256 KiB here);
the driver now keeps a ring of 32 x 8 KiB (libcaer keeps 8 x 8 KiB; both are measured) (:mod:`necviz.drivers.davis.transfers`): ``libusb1``'s asynchronous
transfers (on the emulator, its stand-ins of the package's objects) or, without the package, pyusb reads on a
thread of their own with the decoding on another. libcaer keeps 8 transfers of 8 KiB in flight (``davisOpenInternal`` in ``src/davis.c``: ``usbSetTransfersNumber(8)``,
``usbSetTransfersSize(8192)``; ``usbAllocateTransfers`` and ``usbDataTransferCallback`` in ``src/usb_utils.c``
submit them all and resubmit each as it completes). A transfer ends when its buffer is full or, holding data, at
the FX3's early-packet timer (1 ms); so a large buffer ends early at a low rate, but at a high rate it ends only
when full — a 256 KiB transfer at 12 Mev/s holds ~10 ms of events.

This measures it on the emulated DAVIS346 (realtime, its device clock slowed down ``--scale`` times so the
machine keeps up at full rate; every time below is device time): random DVS events at a low, a medium and the
full rate on a 64 x 48 array (frames included), read through the driver by each reader. Per transfer, when the reader has it decoded: the *delivery delay* of its oldest data (device time now
minus the time of the last data of the previous transfer) and of its newest (now minus its own last time);
p50/p99 over the run, with the transfers per second and the events the device dropped (its FIFO overflowing
between transfers). The emulated sensor is simulated in steps of its scene samples (up to 2 ms), so a transfer's
newest data may be up to a step later than the device's clock: the *newest* column can be negative; the
*oldest* column is the delay that matters (how stale the oldest data of a transfer is when it arrives).

usage: python benchmarks/transfers.py [--scale 0.05] [--seconds 0.3] [--repeat 3] [--json benchmarks/results/transfers.json]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from necviz.bench.timing import machine, write_result  # noqa: E402
from necviz.core.sensor import SensorGeometry  # noqa: E402
from necviz.drivers.davis import CameraOptions, EmulatedDavis346, EmulatorOptions, open_camera  # noqa: E402

RATES = {"low": 0.1e6, "medium": 2e6, "full": 12e6}  # DVS events per second of device time
#: (reader, transfers in flight or buffered, bytes each): the old single read at three sizes, then both rings
READERS = (
    ("single", 1, 8 * 1024),
    ("single", 1, 64 * 1024),
    ("single", 1, 256 * 1024),
    ("libusb1", 8, 8 * 1024),  # libcaer's ring
    ("libusb1", 32, 8 * 1024),  # the driver's default: libcaer's transfer size, more of them in flight
    ("pyusb", 32, 8 * 1024),
)


def measure(rate: float, usb: str, transfers: int, size: int, seconds: float, scale: float) -> dict:
    be = EmulatedDavis346(
        EmulatorOptions(
            scenario="static_lab",
            duration_s=seconds,
            sensor=SensorGeometry(64, 48),
            realtime=True,
            time_scale=scale,
            extra_event_rate=rate,
        )
    )
    options = CameraOptions(usb=usb, transfers=transfers, transfer_size=size, buffer_s=1.0)
    cam = open_camera("emulated", backend=be, options=options)
    oldest, newest, nbytes = [], [], []
    prev = [None]
    decode = cam._decode

    def timed(data):
        packets, t_last, extra = decode(data)
        now = be._wall_us() if be._wall_start is not None else None
        if now is not None and prev[0] is not None:
            oldest.append(now - prev[0])
            newest.append(now - t_last)
            nbytes.append(len(data))
        prev[0] = t_last
        return packets, t_last, extra

    cam.warm_up()  # the decoder's kernels compiled or loaded before the stream starts, as the pipeline does
    cam._decode = timed  # the reader calls it on its thread, as each transfer arrives
    for _ in cam:
        pass
    st = cam.stats
    o, n = np.asarray(oldest[5:]), np.asarray(newest[5:])  # after start-up
    return {
        "rate_ev_s": rate,
        "usb": usb,
        "transfers_in_flight": transfers,
        "transfer_bytes": size,
        "transfers": int(st["transfers"]),
        "transfers_per_s": st["transfers"] / seconds,
        "mean_transfer_bytes": float(np.mean(nbytes)) if nbytes else None,
        "delay_oldest_p50_us": float(np.percentile(o, 50)) if o.size else None,
        "delay_oldest_p99_us": float(np.percentile(o, 99)) if o.size else None,
        "delay_newest_p50_us": float(np.percentile(n, 50)) if n.size else None,
        "delay_newest_p99_us": float(np.percentile(n, 99)) if n.size else None,
        "events_generated": int(be.events_generated),
        "dropped_events": int(st["dropped_events"]),
        "clock_slip_us": int(be.clock_slip_us),
    }


def combine(runs: list[dict]) -> dict:
    """One row from repeated runs of a configuration: the median of each number (a p99 is ~3 transfers of a 0.3 s
    run, so one stall of the loaded machine moves it), the per-run delay percentiles kept beside it."""
    out = dict(runs[0])
    for k, v in runs[0].items():
        vals = [r[k] for r in runs if r[k] is not None]
        if isinstance(v, (int, float)) and not isinstance(v, bool) and vals:
            out[k] = type(v)(np.median(vals)) if isinstance(v, float) else int(np.median(vals))
    for k in ("delay_oldest_p99_us", "delay_oldest_p50_us"):
        out[k + "_runs"] = [r[k] for r in runs]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scale", type=float, default=0.05, help="device seconds per wall second")
    ap.add_argument("--seconds", type=float, default=0.3, help="device seconds per configuration")
    ap.add_argument(
        "--repeat", type=int, default=3, help="runs per configuration, interleaved across readers; the median is kept"
    )
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    result = {
        "command": f"python benchmarks/transfers.py --scale {args.scale:g} --seconds {args.seconds:g} "
        f"--repeat {args.repeat}",
        "scale": args.scale,
        "seconds": args.seconds,
        "repeat": args.repeat,
        "runs": [],
    }
    print(
        f"{'rate':>7s} {'reader':>12s} {'transfer':>9s} {'transfers/s':>11s} {'mean KiB':>8s} {'oldest p50/p99 ms':>18s} "
        f"{'newest p50/p99 ms':>18s} {'dropped':>9s}"
    )
    for label, rate in RATES.items():
        reps: dict = {reader: [] for reader in READERS}
        for _ in range(max(1, args.repeat)):  # interleaved, so a change in the machine's load touches every reader
            for usb, n, size in READERS:
                reps[(usb, n, size)].append(measure(rate, usb, n, size, args.seconds, args.scale))
        for (usb, n, size), runs in reps.items():
            r = combine(runs)
            r["rate"] = label
            result["runs"].append(r)

            def ms(v):
                return "—" if v is None else f"{v / 1000:.2f}"

            print(
                f"{label:>7s} {usb + ' x' + str(n):>12s} {size // 1024:>6d} KiB {r['transfers_per_s']:11.0f} "
                f"{(r['mean_transfer_bytes'] or 0) / 1024:8.1f} "
                f"{ms(r['delay_oldest_p50_us']):>8s}/{ms(r['delay_oldest_p99_us']):<9s} "
                f"{ms(r['delay_newest_p50_us']):>8s}/{ms(r['delay_newest_p99_us']):<9s} {r['dropped_events']:9d}",
                flush=True,
            )
    result["machine"] = machine()
    print(f"load average {result['machine']['load_average']}")
    write_result(result, args.json, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
