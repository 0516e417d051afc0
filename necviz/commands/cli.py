"""The ``necviz`` command: argparse mapped onto the library's option objects (:mod:`necviz.options`).

Every command registers one way: its module (``necviz/commands/NAME.py``) holds a
:class:`~necviz.commands.Command` record (name, help, its flags, what runs it), and
:func:`build_parser` iterates :data:`COMMANDS`. Flag groups several commands share are in
:mod:`necviz.commands.args`.

Exit codes: 0 success; 2 a user mistake or bad input (one line ``necviz: error: …``); 3 an
internal error (one line saying it is a bug, with the traceback saved to a file for the report);
130 interrupted.

Start-up: building the parser imports nothing heavy (no NumPy, Numba, Rerun or controllers), so
``--version``, ``--help`` and a mistyped flag answer at once; each command imports what it needs
when it runs. The names the help lists come from plain constants (:mod:`necviz.names`), which
``tests/test_cli.py`` keeps equal to the registries.
"""

from __future__ import annotations

import argparse
import sys

from necviz import __version__

EXIT_USER = 2
EXIT_BUG = 3


# -- the parser ---------------------------------------------------------------------------------
class Parser(argparse.ArgumentParser):
    """argparse with necviz's one-line errors: ``necviz: error: argument --x: ...`` (no usage block;
    ``necviz COMMAND --help`` shows it), exit code 2. Subcommand parsers are of this class too."""

    def error(self, message: str):
        message = " ".join(str(message).split())
        head, sep, rest = message.partition(": ")
        if sep and head.startswith("argument ") and rest.startswith(head.removeprefix("argument ").split("/")[0]):
            message = rest  # "argument --x: --x = 0 is out of range" -> "--x = 0 is out of range"
        hint = f" (see: {self.prog} --help)" if self.prog != "necviz" else " (see: necviz --help)"
        self.exit(EXIT_USER, f"necviz: error: {message}{hint}\n")


#: every command's module, in the order ``necviz --help`` lists them: ``necviz.commands.MODULE.COMMAND`` (the module is
#: named after its command, except ``benchmarks`` for ``bench``: ``necviz.bench`` is the benchmarks themselves)
COMMANDS = (
    "info",
    "compare",
    "demo",
    "replay",
    "live",
    "devices",
    "benchmarks",
    "calibrate",
    "export",
    "repair",
    "sweep",
)


def build_parser() -> argparse.ArgumentParser:
    import importlib

    p = Parser(prog="necviz", description="Neuromorphic exposure control: estimators, controllers, dashboard.")
    p.add_argument("--version", action="version", version=f"necviz {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = f"necviz.commands.{name}"
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:  # a command left out of this installation
            if e.name != module and not module.startswith(str(e.name)):
                raise
            continue
        mod.COMMAND.register(sub)
    return p


# -- running ------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    code = _main(argv)
    if argv is None:  # the necviz program itself (a test passes its argv and keeps running)
        _leave_if_wedged(code)
    return code


def _leave_if_wedged(code: int) -> None:
    """A Rerun stream whose file writer failed cannot be flushed or dropped without blocking for ever
    (:data:`necviz.dashboard.viewer.WEDGED`): after the error line, leave at once."""
    viewer = sys.modules.get("necviz.dashboard.viewer")
    if viewer is not None and viewer.WEDGED:
        import os

        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _main(argv: list[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):  # file names that are not UTF-8 print as the user typed them
        try:
            stream.reconfigure(errors="surrogateescape")
        except (AttributeError, ValueError, OSError):
            pass
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # a bad flag (one line printed), --help or --version: an exit code, not an exception
        return e.code if isinstance(e.code, int) else (0 if e.code is None else EXIT_USER)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from necviz.core.errors import NecvizError

    _terminate_as_interrupt()
    try:
        return int(args.func(args) or 0)
    except NecvizError as e:  # an option object names its field; the user sees the flag (necviz.flags)
        from necviz.flags import in_flag_terms

        print(f"necviz: error: {' '.join(in_flag_terms(e).split()) or type(e).__name__}", file=sys.stderr)
        return EXIT_USER
    except KeyboardInterrupt:
        print("necviz: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: not an error
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:  # a file or device the user named: missing, unreadable, full disk
        if e.filename is None and not isinstance(e, (FileNotFoundError, PermissionError)):
            return _bug(e, argv)
        print(f"necviz: error: {e.strerror or e}{f': {e.filename}' if e.filename else ''}", file=sys.stderr)
        return EXIT_USER
    except (SystemExit, GeneratorExit):
        raise
    except BaseException as e:  # noqa: BLE001 - the last resort (a Rust panic derives from BaseException)
        return _bug(e, argv)


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _bug(e: BaseException, argv) -> int:
    """An exception necviz did not expect: one line for the user, the traceback in a file for the report."""
    import tempfile
    import time
    import traceback

    text = "".join(traceback.format_exception(e))
    try:
        fd, path = tempfile.mkstemp(prefix=f"necviz-bug-{time.strftime('%Y%m%d-%H%M%S')}-", suffix=".txt")
        with open(fd, "w", encoding="utf-8", errors="backslashreplace") as f:
            f.write(f"necviz {__version__}\ncommand: necviz {' '.join(argv if argv is not None else sys.argv[1:])}\n\n")
            f.write(text)
        where = f"; details in {path}"
    except OSError:
        where = ""
    print(
        f"necviz: internal error: {type(e).__name__}: {_one_line(e)} — this is a bug in necviz, please report it "
        f"with the command you ran{where}",
        file=sys.stderr,
    )
    return EXIT_BUG


def _terminate_as_interrupt() -> None:
    """SIGTERM stops a run like Ctrl-C does, so recordings are flushed (an .rrd killed mid-write has no footer)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, handler)
    except (ValueError, OSError):  # pragma: no cover - not in the main thread of the main interpreter
        pass


if __name__ == "__main__":
    sys.exit(main())
