"""Errors of the DAVIS driver: one-line messages (a remedy may follow on later lines)."""

from __future__ import annotations

from necviz.core.errors import NecvizError


class DeviceError(NecvizError):
    """The camera cannot be used: wrong firmware/logic, permission denied, a failed transfer."""


class DeviceNotFoundError(DeviceError):
    """No DAVIS camera (or not the requested serial) is attached."""


class DeviceDisconnectedError(DeviceError):
    """The camera was unplugged while in use."""
