"""The native recorder behind ``--record``, written so an existing file is never destroyed.

A new file is written under its own name from the first packet on (a crash leaves it readable up
to the last flush); replacing an existing one (``--force``) writes beside it and renames over it
only when the run has ended (:mod:`necviz.outputs`).
"""

from __future__ import annotations

from pathlib import Path

from necviz.outputs import commit_recording, recording_target


class RecordingFile:
    """A native :class:`~necviz.drivers.recordings.native.Recorder` bound for ``path`` (checked beforehand
    with :func:`~necviz.outputs.check_output`); :meth:`close` completes the file."""

    def __init__(self, path, sensor, properties: dict):
        from necviz.drivers.recordings.native import Recorder

        self.path = Path(path)
        self.target = recording_target(path)
        self.recorder = Recorder(self.target, sensor=sensor, properties={k: str(v) for k, v in properties.items()})
        self.closed = False

    def write(self, packet) -> None:
        self.recorder.write(packet)

    def command(self, record) -> None:
        self.recorder.command(record)

    def annotate(self, t_us: int, data: dict) -> None:
        self.recorder.annotate(t_us, data)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.recorder.close()
            commit_recording(self.target, self.path)


def open_recorder(path, sensor, properties: dict) -> RecordingFile:
    return RecordingFile(path, sensor, properties)
