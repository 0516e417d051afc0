"""The data path of the emulated DAVIS346: simulated sensor → 16-bit words → device FIFO → bulk transfers.

:class:`DataPathMixin` is the streaming half of :class:`~necviz.drivers.davis.emulator.EmulatedDavis346`:
it starts the closed-loop simulator (:class:`~necviz.drivers.sim.rig.SimRig`) when the run
registers are on, encodes its packets into the device FIFO (:mod:`.encoder`: DVS events, frames with
their exposure words, IMU samples) and answers bulk reads of endpoint 0x82, checking the unplug and
stall faults on every read. It uses the device model's registers, lock, faults and counters.

Pacing: ``realtime=False`` produces data as fast as it is read (nothing can be lost: the device
waits for the host). ``realtime=True`` runs the sensor on the wall clock (device time = wall time
since streaming started x ``time_scale``; a scale below 1 slows the device so tests can emulate full
rate on a small machine; a simulation that cannot keep up slips the clock, counted in ``clock_slip_us``,
rather than sending stale time in bulk — a sensor never runs ahead of, or catches up on, its clock) and
models the device's buffering:

* **Transfers in flight.** While the host is inside a bulk read, data flows into its buffer; the
  transfer ends when the buffer is full or, holding data, 1 ms of device time after it started
  (the early-packet timer: the FX3 sends a short packet).
* **Transfers waiting.** ``host_buffer_bytes`` (0 unless set by the reader) is the room of the host's other
  transfers submitted and waiting on the endpoint: with several in flight (``libusb1``, :mod:`.emulator_libusb1`
  sets it for each read), data produced while the host is away flow into them, so the device drops only when
  its FIFO *and* those transfers are full — what keeping transfers in flight buys on a camera.
* **Device FIFO.** Between transfers (the host not reading: a busy reader thread, a full host
  queue) data waits in the device, which holds ``fifo_bytes`` (default :data:`FIFO_BYTES` =
  128 KiB: the FPGA's event FIFOs plus the FX3's DMA buffers, an assumption — the FX3 has 512 KiB
  of SRAM in all, shared with its firmware; that is about 2 ms at the DAVIS346's peak of roughly
  70 MB/s). When it is full, DVS events are dropped whole and counted, as the device does with
  ``DROP_DVS_ON_TRANSFER_STALL`` on; the count is what the MUX statistics register
  ``STAT_DVS_DROPPED`` reports (the driver reads it). APS frames wait rather than drop
  (``WAIT_ON_TRANSFER_STALL``): a frame that would start while the FIFO is full is not exposed at
  all (counted in :attr:`EmulatedDavis346.frames_skipped`); timestamps, IMU samples and the words of
  a frame already started are never dropped, so the FIFO may exceed its size by about one frame.

``extra_event_rate`` (events/s of device time) adds uniformly random DVS events to the scene's, a
load generator for full-rate tests; :attr:`EmulatedDavis346.events_generated` counts every DVS
event the sensor produced, :attr:`EmulatedDavis346.dvs_dropped` those the FIFO dropped.
"""

from __future__ import annotations

import errno
import time

import numpy as np
import usb.core

from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.drivers.davis import protocol as P
from necviz.drivers.davis.emulator_usb import _usb_error
from necviz.drivers.davis.encoder import FRAME_END, StreamEncoder, cds_pair

#: device-side buffering assumed for the DAVIS346 FX3 (bytes; see the module docstring)
FIFO_BYTES = 128 * 1024
#: the early-packet timer: a transfer holding data ends this long after it started (device µs)
EARLY_PACKET_US = 1000
#: how far (device µs) the simulation may fall behind the end of the last transfer before the device's clock
#: slips (see ``DataPathMixin._slip``)
SLIP_ALLOWANCE_US = 1000


class DataPathMixin:
    """The streaming methods of :class:`~necviz.drivers.davis.emulator.EmulatedDavis346` (a mixin: the
    device model owns the state they use — registers, ``lock``, ``faults``, the FIFO ``_pending``
    and the counters, set by its ``_power_on``)."""

    # -- streaming -----------------------------------------------------------------------------------
    def warm_up(self) -> None:
        """Compile or load the simulator's kernels on a throwaway rig of the same scenario (a few ms of it)."""
        from necviz.drivers.sim.rig import RigOptions, SimRig
        from necviz.drivers.sim.scenes import make_scenario

        scene = make_scenario(
            self.scenario, sensor=self.sensor, duration_us=50_000, seed=self.seed, **self.scenario_params
        )
        SimRig(scene, ["camera"], seed=self.seed, options=RigOptions(threads=False)).warm_up()

    def _ensure_rig(self) -> None:
        from necviz.drivers.sim.aps import ApsParams
        from necviz.drivers.sim.rig import SimRig
        from necviz.drivers.sim.scenes import make_scenario

        if self._rig is None:
            interval = max(int(round(self.reg(P.APS.MODULE, P.APS.FRAME_INTERVAL) / self.adc_mhz)), 3000)
            aps = ApsParams(frame_interval_us=interval, exposure_max_us=interval - 1000)
            duration_us = None if self.duration_s is None else int(round(self.duration_s * 1e6))
            scene = make_scenario(
                self.scenario, sensor=self.sensor, duration_us=duration_us, seed=self.seed, **self.scenario_params
            )
            exp_us = min(max(self.reg(P.APS.MODULE, P.APS.EXPOSURE) / self.adc_mhz, 1.0), aps.exposure_max_us)
            self._rig = SimRig(scene, {"camera": (exp_us, 1.0)}, aps=aps, seed=self.seed)
            self._gen = self._rig.packets()
        if self._encoder is None:  # streaming (re)starts: device time restarts at 0
            v = self.variant
            self._encoder = StreamEncoder(
                self.aps_orientation, dvs_invert_xy=bool(v.dvs_orientation & 4), layout=v.layout
            )
            self._base_us = self._rig.now_us
            self._pending += self._encoder.timestamp_reset().tobytes()
            self._frame_open = False
            self._next_imu_us = 0
            self._load_us = 0
            self._read_end_us = None
            self._late = 0
            self._wall_start = None if self.realtime else time.monotonic()

    @property
    def device_time_us(self) -> int:
        """Device time of the data produced so far (µs since streaming started)."""
        return 0 if self._encoder is None else self._encoder.now_us

    def _dev_t(self, t: int) -> int:
        return max(int(t) - self._base_us, self._encoder.now_us)

    def _sensor_us(self) -> int:
        """Device time up to which the sensor has been simulated (µs)."""
        return self._rig.now_us - self._base_us

    def _wall_us(self) -> float:
        """Device time the wall clock has reached since streaming started (realtime; µs)."""
        return (time.monotonic() - self._wall_start) * 1e6 * self.time_scale

    def _room(self) -> int | None:
        """Free bytes in the device FIFO (None: unbounded — not realtime, the device waits for the host;
        or data the emulator is late producing for a time when the host was reading)."""
        return (
            self.fifo_bytes + self.host_buffer_bytes - self._fill() if self.realtime and not self._unbounded else None
        )

    def _fill(self) -> int:
        """Bytes in the FIFO that occupy it (data produced late, see :meth:`_bulk_read_realtime`, do not)."""
        return len(self._pending) - self._late

    def _with_load(self, ev: np.ndarray, upto: int) -> np.ndarray:
        """``ev`` plus uniformly random events at ``extra_event_rate`` over [last load time, ``upto``) µs."""
        lo = max(self._load_us, self._encoder.now_us)
        if self.extra_event_rate <= 0 or upto <= lo:
            self._load_us = max(self._load_us, upto)
            return ev
        rng = self._load_rng
        n = int(rng.poisson(self.extra_event_rate * (upto - lo) / 1e6))
        self._load_us = upto
        if n == 0:
            return ev
        load = np.empty(n, EVENT_DTYPE)
        load["t"] = np.sort(rng.integers(lo, upto, n))
        load["x"] = rng.integers(0, self.sensor.width, n)
        load["y"] = rng.integers(0, self.sensor.height, n)
        load["p"] = rng.integers(0, 2, n, dtype=np.int8) * 2 - 1
        if ev.size == 0:
            return load
        both = np.concatenate([ev, load])
        return both[np.argsort(both["t"], kind="stable")]

    def _put_events(self, ev: np.ndarray) -> None:
        """Encode DVS events into the FIFO; in realtime, those that do not fit are dropped and counted."""
        if ev.size == 0:
            return
        enc = self._encoder
        n = ev.size
        self.events_generated += n
        room = self._room()
        if room is None:
            self._pending += enc.events(ev).tobytes()
            return
        if room <= 0:
            self.dvs_dropped += n
            return
        saved = enc.state.copy()
        words = enc.events(ev)
        k = n
        while words.nbytes > room and k > 0:  # keep the first k events that fit (k strictly decreases)
            enc.state[:] = saved
            k = k * room // words.nbytes
            words = enc.events(ev[:k]) if k else np.zeros(0, np.uint16)
        self.dvs_dropped += n - k
        self._pending += words.tobytes()

    def _put(self, words: np.ndarray) -> None:
        """Words the device never drops (time, specials, APS samples, IMU): into the FIFO whatever its fill."""
        self._pending += words.tobytes()

    def _produce(self, until: int | None = None) -> bool:
        """Simulate the sensor up to device time ``until`` µs (default: 1 ms on), encoding into the FIFO;
        False when the scenario is over."""
        enc = self._encoder
        r = self.reg
        if until is None:
            until = self._sensor_us() + 1000
        while self._sensor_us() < until:
            try:
                _, pk = next(self._gen)
            except StopIteration:
                self._scene_done = True
                break
            if isinstance(pk, EventBatch):
                if r(P.DVS.MODULE, P.DVS.RUN):
                    ev = pk.events
                    if self._base_us:
                        ev = ev.copy()
                        ev["t"] -= self._base_us
                    ev = ev[ev["t"] >= enc.now_us]
                    upto = int(ev["t"][-1]) + 1 if ev.size else self._sensor_us() + 1
                    self._put_events(self._with_load(ev, upto))
                if r(P.IMU.MODULE, P.IMU.RUN_ACCELEROMETER) and enc.now_us >= self._next_imu_us:
                    self._put(enc.imu(enc.now_us, (0, -8192, 0, -1700, 0, 0, 0), accel_scale=1, gyro_scale=1))
                    self._next_imu_us = enc.now_us + 1000
            elif isinstance(pk, ExposureMarker):
                t = self._dev_t(pk.t_us)
                if r(P.DVS.MODULE, P.DVS.RUN):
                    self._put_events(self._with_load(np.zeros(0, EVENT_DTYPE), t))
                t = max(t, enc.now_us)
                if pk.kind == "start":
                    self._frame_open = bool(r(P.APS.MODULE, P.APS.RUN))
                    if (
                        self._frame_open
                        and self.realtime
                        and not self._unbounded
                        and self._fill() >= self.fifo_bytes + self.host_buffer_bytes
                    ):
                        self._frame_open = False  # the APS waits on the stalled transfer: no frame
                        self.frames_skipped += 1
                    if self._frame_open:
                        cycles = int(round(self._rig.cams["camera"].exposure_us * self.adc_mhz))
                        cycles += self.variant.echo_offset_cycles
                        roi = self._roi()
                        self._frame_roi = roi
                        h, w = roi[3] - roi[1] + 1, roi[2] - roi[0] + 1
                        gs = bool(r(P.APS.MODULE, P.APS.GLOBAL_SHUTTER))
                        self._put(enc.frame_start(t, roi, cycles, gs))
                        self._put(enc.readout(np.full((h, w), 1023, np.int64), False))
                        self._put(enc.exposure_special(t, True))
                elif self._frame_open:  # the exposure ends and the signal read starts
                    self._put(enc.exposure_special(t, False))
                    self._put(enc.signal_start(t))
            elif isinstance(pk, Frame) and self._frame_open:
                c0, r0, c1, r1 = self._frame_roi
                _, signal = cds_pair(pk.image[r0 : r1 + 1, c0 : c1 + 1], adc_shift=self._adc_shift)
                self._put(enc.readout(signal, True, first_started=True))
                self._put(enc.special(self._dev_t(self._rig.now_us), FRAME_END))
                self._frame_open = False
        if not self._unbounded:
            self.fifo_peak = max(self.fifo_peak, self._fill())
        return not self._scene_done

    def _roi(self) -> tuple[int, int, int, int]:
        w, h = self.sensor.width, self.sensor.height
        r = self.reg
        c0 = min(r(P.APS.MODULE, P.APS.START_COLUMN_0), w - 1)
        r0 = min(r(P.APS.MODULE, P.APS.START_ROW_0), h - 1)
        c1 = min(max(r(P.APS.MODULE, P.APS.END_COLUMN_0), c0), w - 1)
        r1 = min(max(r(P.APS.MODULE, P.APS.END_ROW_0), r0), h - 1)
        return c0, r0, c1, r1

    def _faults_and_state(self, ep) -> bool:
        """Checks every bulk read makes (unplug, halt, injected faults); returns whether the device streams."""
        self._check_plug()
        if ep != P.DATA_ENDPOINT:
            raise _usb_error(errno.EPIPE, "Pipe error")
        if self._halted:
            raise _usb_error(errno.EPIPE, "Pipe error")
        f = self.faults
        if f.unplug_after_s is not None and self.device_time_us >= f.unplug_after_s * 1e6:
            self.plugged = False
            self._unplugged_at = time.monotonic()
            raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")
        if f.stall_after_s is not None and not self._stalled_once and self.device_time_us >= f.stall_after_s * 1e6:
            self._stalled_once = True
            self._halted = True
            self.stalls += 1
            raise _usb_error(errno.EPIPE, "Pipe error")
        running = self._running()
        if running:
            with self._data_lock:  # the FIFO and the encoder belong to the data path
                self._ensure_rig()
        elif self._encoder is not None and not self.reg(P.USB.MODULE, P.USB.RUN):
            self._encoder = None  # stopped: the next start restarts device time
        return running

    def _take(self, view, got: int) -> int:
        """Move FIFO bytes into the host buffer ``view`` after its first ``got`` bytes; returns the new fill."""
        n = min(len(view) - got, len(self._pending))
        if n:
            view[got : got + n] = self._pending[:n]
            del self._pending[:n]
            self._late = max(0, self._late - n)
        return got + n

    def take_full(self, buff) -> int:
        """Fill the host buffer ``buff`` from the FIFO at once if the FIFO holds enough to fill it (a transfer
        waiting behind one that just ended full is filled at bus speed, without the sensor advancing); returns the
        bytes moved, 0 if the FIFO holds less (the transfer then waits for data as a read does) or the endpoint
        cannot deliver (halted, unplugged: the next read says why)."""
        view = memoryview(buff).cast("B")
        with self._data_lock:
            if not self.plugged or self._halted or len(self._pending) < len(view):
                return 0
            n = self._take(view, 0)
            self.bulk_reads += 1
            return n

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        timeout_s = (timeout or 1000) / 1000.0
        if self.realtime:
            return self._bulk_read_realtime(ep, buff, timeout_s)
        with self.lock:
            running = self._faults_and_state(ep)
            produce = running and not self._pending and not self._scene_done
        if produce:  # simulate without the control lock: a control transfer (an exposure command) does not
            with self._data_lock:  # wait for the simulator, as a real device's does not wait for its sensor
                self._produce()
        with self._data_lock:
            n = self._take(memoryview(buff).cast("B"), 0)
            if n:
                self.bulk_reads += 1
            elif running and self._scene_done:
                self.stream_finished = True
        if n:
            return n
        time.sleep(min(timeout_s, 0.01))
        raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)

    def _bulk_read_realtime(self, ep, buff, timeout_s: float) -> int:
        """One transfer on the wall clock (see the module docstring): the data produced since the last
        transfer ended waited in the FIFO (bounded: DVS events dropped when full); from now on data
        flows into this transfer until it is full or the early-packet timer ends it.

        The emulator may itself fall behind the wall clock (a loaded machine); it then slips its clock
        (:meth:`_slip`), and what it produces late (at most :data:`SLIP_ALLOWANCE_US`) for a time when the
        host was reading is not limited by the FIFO: only the time between two transfers is. That holds only
        when the FIFO was empty (the host waiting for data): behind a backlog they would have queued in the FIFO,
        so they are bounded by it.

        A read the FIFO can fill whole is served from it at once, without simulating the sensor first (a camera
        serves it at bus speed; simulating on the host's thread would make the host pay the sensor's cost for
        every small read of a backlog); the time it took still counts as the host's absence (bounded by the FIFO)
        at the next read that simulates."""
        if ep == P.DATA_ENDPOINT and self._running():
            n = self.take_full(buff)
            if n:
                return n
        try:
            return self._transfer(ep, buff, timeout_s)
        finally:
            if self._wall_start is not None:
                self._read_end_us = self._wall_us()

    def _slip(self) -> None:
        """A simulation slower than the wall clock slips the device's clock instead of catching up in bulk.

        The data of the last transfer's time should have flowed into it as it was sensed; if the simulator had
        not produced it by the time the transfer ended (a loaded machine, a costly light step), a real sensor
        would not have it later either — it senses now. Device time 0 moves later by the shortfall beyond
        :data:`SLIP_ALLOWANCE_US` (counted in ``clock_slip_us``), so the sensor never produces a burst of
        stale time that a command written meanwhile could not affect; the time the host spends between
        transfers is not touched (it still fills, then overflows, the FIFO)."""
        late = self._read_end_us
        behind = None if late is None else late - SLIP_ALLOWANCE_US - self._sensor_us()
        if behind is not None and behind > 0:
            self._wall_start += behind / 1e6 / self.time_scale
            self._read_end_us = late - behind
            self.clock_slip_us += int(behind)

    def _transfer(self, ep, buff, timeout_s: float) -> int:
        view = memoryview(buff).cast("B")
        t0 = time.monotonic()
        got = 0
        first = True
        while True:
            with self.lock:  # registers and faults: held only for the checks, never while simulating
                running = self._faults_and_state(ep)
            # the sensor is simulated under the data lock alone: a control transfer (an exposure command) is
            # served meanwhile, as a real device's control endpoint does not wait for its sensor
            with self._data_lock:
                if running and not self._scene_done and self._wall_start is None:
                    # the simulator's first packet takes a while (start-up): device time 0 is when it is ready
                    self._produce(1)
                    self._wall_start = time.monotonic()
                if running and not self._scene_done:
                    if first:
                        self._slip()
                    target = self._wall_us()
                    if first:  # the gap since the last transfer: everything goes through the FIFO
                        late = self._read_end_us
                        # only into an empty FIFO: the host was waiting, so those data would have flowed straight
                        # into its transfer; behind a backlog (the last transfer ended full, as back-to-back ring
                        # transfers do) they queue in the FIFO like any other, within its size
                        if late is not None and self._sensor_us() < late and self._fill() == 0:
                            self._unbounded = True  # late production for the previous transfer's time
                            try:
                                self._produce(int(late))
                            finally:
                                self._unbounded = False
                            self._late = len(self._pending)
                        self._produce(int(target))
                    else:  # inside the transfer: up to 1 ms at a time, never past the wall clock, each straight on
                        while (  # to the host
                            self._sensor_us() < target
                            and got < len(view)
                            and self._produce(min(self._sensor_us() + 1000, int(target) + 1))
                        ):
                            got = self._take(view, got)
                got = self._take(view, got)
                finished = running and self._scene_done and not self._pending
                if finished and not got:
                    self.stream_finished = True
            if finished and not got:
                time.sleep(min(timeout_s, 0.01))
                raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)
            first = False
            elapsed = time.monotonic() - t0
            if got == len(view) or (got and (finished or elapsed * 1e6 * self.time_scale >= EARLY_PACKET_US)):
                self.bulk_reads += 1
                return got
            if elapsed >= timeout_s:
                if got:
                    self.bulk_reads += 1
                    return got
                raise usb.core.USBTimeoutError("Operation timed out", error_code=None, errno=errno.ETIMEDOUT)
            time.sleep(min(0.002, max(0.0002, 250e-6 / self.time_scale)))
