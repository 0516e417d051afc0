"""The source interface shared by the simulator, the live DAVIS driver and the file replayers.

A source is one or more cameras that share a sensor geometry and, where they share a scene, one
event stream. :meth:`Source.packets` yields ``(camera, packet)`` pairs in stream order:

* ``(None, batch)`` for event batches (:class:`~necviz.core.events.EventBatch`), which every camera
  of the source shares (a single camera's events are "shared" by its one camera);
* ``(name, packet)`` for what belongs to one camera: :class:`~necviz.core.frames.ExposureMarker`,
  :class:`~necviz.core.frames.Frame`, and optional :class:`~necviz.core.imu.ImuBatch` and
  :class:`~necviz.core.imu.TriggerBatch`.

A single camera is a source with one name in :attr:`Source.cameras` (``"camera"`` by default);
:func:`route` turns a plain packet iterator into such pairs. Commands go back with
:meth:`Source.set_exposure`, which has the same signature everywhere: the source stamps each
command with its own clock (the time of the last packet it delivered), because a command cannot
be issued before the packet that caused it arrived. ``issue_time_us`` exists for tests that need
to place a command at an exact time. Recordings accept commands and ignore them (replay is open
loop). The pipeline never needs to know whether a source is simulated, live or recorded.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from necviz.core.control.controller import CameraLimits
from necviz.core.events import EventBatch
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import Packet

if TYPE_CHECKING:
    from necviz.drivers.sim.dvs import DvsParams

#: The name of the only camera of a single-camera source.
CAMERA = "camera"


@dataclass(frozen=True)
class CommandRecord:
    """An exposure command as the camera received it, and when it took effect.

    ``applied_start_us`` is the start of the first exposure that used it (``None``: superseded
    or not yet applied).
    """

    issue_time_us: int
    exposure_us: float
    gain: float
    applied_start_us: int | None = None


@dataclass(frozen=True)
class CameraInfo:
    """What a source knows about its cameras (``None`` where it does not know, e.g. a recording).

    Parameters
    ----------
    limits : CameraLimits, optional
        The exposure and gain the cameras accept.
    command_latency_us : float, optional
        A command takes effect at the first exposure starting at least this long after it was issued.
    event_rate_max : float, optional
        The sensor's event bus ceiling (events per second, sensor-wide): beyond it events are lost.
    frame_interval_us : float, optional
        The frame period.
    """

    limits: CameraLimits | None = None
    command_latency_us: float | None = None
    event_rate_max: float | None = None
    frame_interval_us: float | None = None


@runtime_checkable
class Source(Protocol):
    """One camera, or a rig of cameras sharing a scene (see the module docstring).

    ``camera_info`` says what the source knows about its cameras (limits, command latency, event bus
    ceiling); ``warm_up`` readies its kernels before the first packet (start-up is never latency);
    ``close`` releases it (a device, a file) and may be called more than once.

    The members with defaults below are what a source may add; a source states it by subclassing
    :class:`Source` (the defaults then hold for what it does not override): ``stats``, what a camera lost
    (``dropped_events`` ...) for the run's summary; ``annotations``, notes stored beside the packets (a
    native recording's DVS bias changes, ``[(t_us, dict), ...]``); the DVS members, for a source that takes
    bias changes (``takes_dvs_biases``; :mod:`necviz.dvs_controls`).
    """

    sensor: SensorGeometry
    cameras: tuple[str, ...]
    camera_info: CameraInfo
    #: notes recorded beside the packets, ``[(t_us, dict), ...]`` (a native recording); empty elsewhere
    annotations: Sequence = ()
    #: the bias table of the DVS chip: ``"DAVIS346"`` or ``"DAVIS240"``
    dvs_family: str = "DAVIS346"
    #: :meth:`set_dvs_biases` writes bias words (the simulator, the cameras); ``False``: no bias changes
    takes_dvs_biases: bool = False

    @property
    def stats(self) -> dict:
        """What the device lost and how the host kept up (a camera: ``dropped_events``, ``skipped_words``,
        ``reconnects`` ...); empty for a source that loses nothing."""
        return {}

    @property
    def dvs_pixel(self) -> DvsParams | None:
        """The simulated pixel at libcaer's default biases where there is one (the simulator, the emulated
        camera); ``None``: a real camera (the bias model then estimates it)."""
        return None

    def packets(self) -> Iterator[tuple[str | None, Packet]]: ...

    def set_exposure(
        self, camera: str, exposure_us: float, gain: float = 1.0, *, issue_time_us: int | None = None
    ) -> None: ...

    def close(self) -> None: ...

    def warm_up(self) -> None:
        """Compile or load what the source's own kernels need, before its first packet (may do nothing)."""

    def set_dvs_biases(self, words: dict[int, int]) -> None:
        """Write DVS bias words (module-5 parameter -> word, :mod:`necviz.core.biases`); only where
        ``takes_dvs_biases``."""
        raise NotImplementedError(f"{type(self).__name__} takes no DVS bias changes")

    def dvs_applied_us(self) -> int | None:
        """Stream time from which the last DVS bias change holds (``None``: not yet, or no change)."""
        return None


def route(camera: str, packets: Iterable[Packet]) -> Iterator[tuple[str | None, Packet]]:
    """A single camera's packet stream as :meth:`Source.packets` pairs (events shared, the rest ``camera``'s)."""
    for packet in packets:
        yield (None if isinstance(packet, EventBatch) else camera), packet


__all__ = ["CAMERA", "CameraInfo", "CommandRecord", "Packet", "Source", "route"]
