"""ROS1 / ROS2 bags with ``dvs_msgs/EventArray``, ``sensor_msgs/Image``, the exposure topic and IMU (``rosbags``).

Topics are chosen by message type: the first ``dvs_msgs/EventArray`` topic (alphabetically; a
warning names the others), the ``sensor_msgs/Image`` topic in the same namespace (preferring
``image_raw``), the ``std_msgs/Int32`` topic ending in ``exposure`` (µs, as published by
rpg_dvs_ros) and ``sensor_msgs/Imu``.

* Events: ``(0,0)`` top-left; ``ts`` (sec, nsec) -> integer µs (rounded); polarity bool -> ±1.
  ROS1 messages are decoded straight from their serialised bytes with NumPy (13 bytes per event:
  ``u16 x, u16 y, u32 sec, u32 nsec, u8 polarity``), no per-event Python; ROS2 (CDR) messages go
  through rosbags' deserialiser, which builds one Python object per event (slow for large bags).
* Frames: ``Image.header.stamp`` is the mid-exposure time (rpg_dvs_ros), so the exposure is
  ``[stamp - exp/2, stamp + exp/2]`` with ``exp`` the latest exposure message (exposure_source
  ``"stored"``), or ``exposure_us`` when the bag has no exposure topic; without either, frames are
  skipped with a warning. mono16 keeps its 8 most significant bits, colour becomes luma.
* IMU: ``linear_acceleration`` (m/s² -> g), ``angular_velocity`` (rad/s -> °/s); temperature NaN.

Messages are read in bag order (receive time) and held back like AEDAT frames
(:class:`~.base.StreamAssembler`). Seeking: rosbags filters messages by bag time (``start``) with a
margin of 2 s before ``start_us``; the bag clock is assumed to be the sensor clock.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings.reader import (
    NO_EXPOSURE_FRAMES,
    G,
    Recording,
    RecordingError,
    StreamAssembler,
    openable_path,
    reason,
    to_gray8,
)

DVS_MSGS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n",
    "dvs_msgs/msg/EventArray": "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n",
}
ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])


def _close(reader) -> None:
    """Close a rosbags reader; closing a damaged bag may fail too, which changes nothing."""
    try:
        reader.close()
    except Exception:  # noqa: BLE001
        pass
    names = getattr(reader, "_necviz_names", None)
    if names is not None:
        names.close()


def _stamp_us(stamp) -> int:
    return int(stamp.sec) * 1_000_000 + (int(stamp.nanosec) + 500) // 1000


class RosbagRecording(Recording):
    """Replay a ROS1 ``.bag`` or a ROS2 bag directory (see the module docstring)."""

    format = "rosbag"

    def __init__(self, path, **kwargs):
        super().__init__(path, **kwargs)
        self._reader = None
        reader = self._open_reader()
        try:
            self._inspect(reader)
        except RecordingError:
            raise
        except Exception as exc:  # noqa: BLE001 - rosbags/apsw/mcap raise their own types on a damaged bag
            raise self.error(f"unreadable bag ({reason(exc)})", self._where) from None
        finally:
            _close(reader)
        if self.image_topic is None:
            self.exposure_source = "none (no frames)"
        elif self.exposure_topic is not None:
            self.exposure_source = "stored"
        elif self.exposure_us is not None:
            self.exposure_source = "user (--exposure-us)"
        else:
            self.exposure_source = NO_EXPOSURE_FRAMES
        self.properties = {
            "event_topic": self.event_topic,
            "image_topic": self.image_topic,
            "exposure_topic": self.exposure_topic,
            "imu_topic": self.imu_topic,
        }

    def _inspect(self, reader) -> None:
        """Choose the topics (and read the sensor size from the first EventArray if needed)."""
        self._where = "the bag's connection table"
        self.ros1 = not self.path.is_dir() and self.path.suffix != ".mcap" and self.path.suffix != ".db3"
        self.format = "rosbag1" if self.ros1 else "rosbag2"
        conns = reader.connections
        by_type = {}
        for c in conns:
            by_type.setdefault(c.msgtype.rsplit("/", 1)[-1], []).append(c)
        evs = sorted(by_type.get("EventArray", []), key=lambda c: c.topic)
        if not evs:
            raise self.error(
                "no dvs_msgs/EventArray topic (topics: " + ", ".join(sorted({c.topic for c in conns})) + ")"
            )
        self.event_topic = evs[0].topic
        others = sorted({c.topic for c in evs} - {self.event_topic})
        if others:
            self.warn(f"replaying events of {self.event_topic}; other event topics ignored: {', '.join(others)}")
        ns = self.event_topic.rsplit("/", 1)[0]
        imgs = [c for c in by_type.get("Image", []) if c.msgtype == "sensor_msgs/msg/Image"]
        imgs.sort(key=lambda c: (not c.topic.startswith(ns + "/"), "image_raw" not in c.topic, c.topic))
        self.image_topic = imgs[0].topic if imgs else None
        exps = [c for c in by_type.get("Int32", []) if c.topic.endswith("exposure")]
        exps.sort(key=lambda c: (not c.topic.startswith(ns + "/"), c.topic))
        self.exposure_topic = exps[0].topic if exps else None
        imus = sorted(by_type.get("Imu", []), key=lambda c: (not c.topic.startswith(ns + "/"), c.topic))
        self.imu_topic = imus[0].topic if imus else None
        self._topics = {self.event_topic, self.image_topic, self.exposure_topic, self.imu_topic} - {None}
        if self.sensor is None:
            first = next(c for c in conns if c.topic == self.event_topic)
            for k, (conn, _, raw) in enumerate(reader.messages(connections=[first])):
                self._where = f"message {k} of {self.event_topic}"
                m = reader.deserialize(raw, conn.msgtype)
                if m.width and m.height:
                    self.sensor = SensorGeometry(int(m.width), int(m.height))
                    break
        if self.sensor is None:
            raise self.error("EventArray messages declare no width/height; pass a sensor geometry")

    def _open_reader(self):
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.ROS2_HUMBLE if self.path.is_dir() else Stores.ROS1_NOETIC)
        types = {}
        for name, text in DVS_MSGS.items():
            types.update(get_types_from_msg(text, name))
        try:
            store.register(types)
        except Exception:  # noqa: BLE001 - already registered / conflicting definitions from the bag win
            pass
        reader = None
        names = ExitStack()  # a bag whose name is not UTF-8 is opened through /proc/self/fd (SQLite needs text)
        try:
            path = Path(names.enter_context(openable_path(self.path)))
            reader = AnyReader([path], default_typestore=store)
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises its own error types with a message
            if reader is not None:
                _close(reader)
            names.close()
            raise self.error(f"unreadable bag ({reason(exc)})", "its index/metadata") from None
        reader._necviz_names = names  # closed with the reader (_close)
        return reader

    def _events(self, reader, conn, raw) -> np.ndarray:
        if self.ros1:
            # header: seq u32, stamp (u32, u32), frame_id (u32 length + bytes); height u32, width u32, n u32
            n_id = int(np.frombuffer(raw, "<u4", 1, 12)[0])
            off = 16 + n_id + 8
            n = int(np.frombuffer(raw, "<u4", 1, off)[0])
            rec = np.frombuffer(raw, ROS1_EVENT, n, off + 4)
            ev = np.empty(n, EVENT_DTYPE)
            ev["t"] = rec["sec"].astype(np.int64) * 1_000_000 + (rec["nsec"].astype(np.int64) + 500) // 1000
            ev["x"] = rec["x"]
            ev["y"] = rec["y"]
            ev["p"] = np.where(rec["p"] > 0, 1, -1)
            return ev
        m = reader.deserialize(raw, conn.msgtype)
        es = m.events
        n = len(es)
        ev = np.empty(n, EVENT_DTYPE)
        ev["t"] = np.fromiter((e.ts.sec * 1_000_000 + (e.ts.nanosec + 500) // 1000 for e in es), np.int64, n)
        ev["x"] = np.fromiter((e.x for e in es), np.uint16, n)
        ev["y"] = np.fromiter((e.y for e in es), np.uint16, n)
        ev["p"] = np.fromiter((1 if e.polarity else -1 for e in es), np.int8, n)
        return ev

    def _packets(self) -> Iterator:
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        self._asm = asm
        reader = self._open_reader()
        exposure = None
        lag, seq, no_exposure = 0, 0, 0
        kw = {}
        if self.start_us is not None:
            kw["start"] = max(0, (self.start_us - 2_000_000) * 1000)
        try:
            try:
                conns = [c for c in reader.connections if c.topic in self._topics]
                for k, (conn, bag_t, raw) in enumerate(reader.messages(connections=conns, **kw)):
                    topic = conn.topic
                    self._where = f"message {k} ({topic}, bag time {bag_t} ns)"
                    if topic == self.event_topic:
                        ev = self._events(reader, conn, raw)
                        if ev.size and np.any(ev["t"][1:] < ev["t"][:-1]):
                            ev = ev[np.argsort(ev["t"], kind="stable")]
                        asm.push_events(ev)
                    elif topic == self.exposure_topic:
                        exposure = float(reader.deserialize(raw, conn.msgtype).data)
                    elif topic == self.image_topic:
                        m = reader.deserialize(raw, conn.msgtype)
                        stamp = _stamp_us(m.header.stamp)
                        span = self.frame_exposure_from_stamp(stamp, exposure)
                        if span is None:
                            no_exposure += 1
                            continue
                        lag = max(lag, asm.lag_of(span[0]))
                        asm.push_frame(Frame(self._image(m), span[0], span[1], 1.0, seq))
                        seq += 1
                    elif topic == self.imu_topic:
                        m = reader.deserialize(raw, conn.msgtype)
                        imu = np.zeros(1, IMU_DTYPE)
                        imu["t"] = _stamp_us(m.header.stamp)
                        a, w = m.linear_acceleration, m.angular_velocity
                        imu["ax"], imu["ay"], imu["az"] = a.x / G, a.y / G, a.z / G
                        imu["gx"], imu["gy"], imu["gz"] = np.degrees([w.x, w.y, w.z])
                        imu["temp"] = np.nan
                        asm.push_imu(imu)
                    watermark = asm.holdback_watermark(lag)
                    if watermark is not None and (self.start_us is None or watermark > self.start_us):
                        yield from asm.drain(watermark)
                    if watermark is not None and self.past_end(watermark):
                        break
            except RecordingError:
                raise
            except Exception as exc:  # noqa: BLE001 - rosbags/apsw/mcap/NumPy on a damaged bag
                where = self._where
                yield from asm.drain(None)
                raise self.error(f"damaged bag ({reason(exc)})", where) from None
            yield from asm.drain(None)
        finally:
            _close(reader)
            if no_exposure:
                self.warn(f"{no_exposure} frames skipped: no exposure message before them; pass --exposure-us")

    @staticmethod
    def _image(m) -> np.ndarray:
        h, w, enc = int(m.height), int(m.width), str(m.encoding).lower()
        data = np.asarray(m.data, np.uint8)
        if enc in ("mono16", "16uc1"):
            img = data.view("<u2" if not m.is_bigendian else ">u2").reshape(h, w)
            return to_gray8(img.astype(np.uint16), 16)
        if enc in ("bgr8", "rgb8", "bgra8", "rgba8"):
            ch = 4 if "a" in enc[3:] else 3
            img = data.reshape(h, w, ch)
            if enc.startswith("rgb"):
                img = img[:, :, [2, 1, 0]]
            return to_gray8(img)
        return data[: h * int(m.step)].reshape(h, int(m.step))[:, :w].copy()
