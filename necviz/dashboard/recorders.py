"""The native recorder behind ``--record``, written so an existing file is never destroyed.

A new file is written under its own name from the first packet on (a crash leaves it readable up
to the last flush); replacing an existing one (``--force``) writes beside it and renames over it
only when the run has succeeded (:class:`~necviz.outputs.StreamedOutput`). A run that fails
deletes what it wrote, unless ``keep_partial`` (a camera session, which cannot be recorded again).
"""

from __future__ import annotations

from pathlib import Path

from necviz.outputs import StreamedOutput


class RecordingFile:
    """A native :class:`~necviz.drivers.recordings.native.Recorder` bound for ``path`` (checked beforehand
    with :func:`~necviz.outputs.check_output`); :meth:`close` completes the file, the command then
    :meth:`commit` s or :meth:`discard` s it."""

    def __init__(self, path, sensor, properties: dict, keep_partial: bool = False):
        from necviz.drivers.recordings.native import Recorder

        self.path = Path(path)
        self.output = StreamedOutput(path, keep_partial=keep_partial, flag="--record")
        try:
            self.recorder = Recorder(
                self.output.target, sensor=sensor, properties={k: str(v) for k, v in properties.items()}
            )
        except BaseException:
            self.output.discard()
            raise
        self.closed = False

    @property
    def target(self) -> Path:
        return self.output.target

    def write(self, packet) -> None:
        self.recorder.write(packet)

    def command(self, record) -> None:
        self.recorder.command(record)

    def annotate(self, t_us: int, data: dict) -> None:
        self.recorder.annotate(t_us, data)

    def close(self) -> None:
        """End the file (END chunk, fsync). Raises what writing it raised (a full disk)."""
        if not self.closed:
            self.closed = True
            self.recorder.close()

    def commit(self) -> None:
        """The run succeeded: the file takes its final name."""
        self.close()
        self.output.commit()

    def discard(self) -> str:
        """The run failed: delete (or keep, see the module docstring) the file; returns what happened."""
        try:
            self.close()
        except BaseException:  # noqa: BLE001 - the run's own error is the one reported
            pass
        return self.output.discard()


def open_recorder(path, sensor, properties: dict, keep_partial: bool = False) -> RecordingFile:
    return RecordingFile(path, sensor, properties, keep_partial)
