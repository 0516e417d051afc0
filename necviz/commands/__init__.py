"""The ``necviz`` commands: one module per command, each holding its :class:`Command` record.

:mod:`necviz.commands.cli` iterates :data:`necviz.commands.cli.COMMANDS` and registers every record the
same way (:meth:`Command.register`). A command module imports nothing heavy at module level (the parser
is built from every record, and ``necviz --help`` must answer at once); what a command needs is imported
when it runs.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True, kw_only=True)
class Command:
    """One ``necviz`` command: its name and help, the flags it adds to its parser, and what runs it.

    ``run`` takes the parsed flags and returns the exit code (it builds the command's option objects
    and calls the library); ``add_arguments`` adds the command's flags (and subcommands, if any) to the
    parser made for it.
    """

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str | None = None

    def register(self, subparsers) -> argparse.ArgumentParser:
        """Add this command to an ``argparse`` subparsers object; returns its parser."""
        p = subparsers.add_parser(self.name, help=self.help, description=self.description)
        self.add_arguments(p)
        p.set_defaults(func=self.run)
        return p


__all__ = ["Command"]
