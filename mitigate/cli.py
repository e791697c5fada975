"""The ``mitigate`` command line.

Each sub-command lives in ``mitigate/commands/<name>.py`` and exposes
``register(subparsers)``; the parser it adds sets ``func`` to a ``run(args) -> int``.
Bad input (``ConfigError``, ``DataError``) and solver failures become one line on
stderr and exit code 2; there is never a traceback for bad input.  A controller or
estimator that broke its contract outside a run (``PluginError``) is one line and exit 1;
inside ``run``/``benchmark`` it fails only its run, and the command exits 1.  Ctrl-C and
SIGTERM end the command cleanly (workers stopped, no half-written output), exit 130 / 143.
With ``--json`` every such ending is also one JSON document on stdout (:func:`error_document`:
``{"command", "status": "error", "kind", "exit_code", "message"}``), so that a script reading
stdout never gets an empty document; the line on stderr stays.
Set ``MITIGATE_DEBUG=1`` to see tracebacks of internal errors.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

# The workbench's matrices are tiny (7-20 states): threaded BLAS only adds contention and
# made the MHE's p95 jump past 100 ms on 2 cores.  Set before numpy is first imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from models.errors import QUOTE_LIMIT, ConfigError, DataError, PluginError, SolverFailure, shorten

COMMANDS = ("simulate", "modal", "identify", "estimate", "run", "sweep", "benchmark", "tune", "export")


#: the command line asked for ``--json``, and the sub-command it names (set by :func:`main` before
#: parsing, so that argparse's own refusals are documents too)
_json_wanted = False
_named_command: str | None = None


def error_document(command: str | None, kind: str, exit_code: int, message: str) -> dict:
    """The JSON document of a command that ended without a result (``--json``).

    Parameters
    ----------
    command : the sub-command (None: the command line named none)
    kind : ``"usage"`` (argparse), ``"input"`` (bad input or a solver failure), ``"plugin"``,
        ``"interrupted"``, ``"terminated"``, ``"internal"``
    exit_code : the process's exit code
    message : the one line written on stderr
    """
    return {"command": command, "status": "error", "kind": kind, "exit_code": exit_code, "message": message}


def _fail(command: str | None, kind: str, exit_code: int, line: str) -> int:
    """Write ``line`` on stderr and, with ``--json``, its document on stdout; return the exit code."""
    sys.stderr.write(line + "\n")
    if _json_wanted:
        from mitigate.cliutil import emit_json   # the commands' own writer (numpy: imported only here)
        try:
            emit_json(error_document(command, kind, exit_code, line))
            sys.stdout.flush()
        except (BrokenPipeError, ValueError):   # the reader went away, or stdout is closed
            pass
    return exit_code


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message):  # noqa: D401
        sys.exit(_fail(_named_command, "usage", 2, f"{self.prog}: error: {message} (see --help)"))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mitigate",
        description="Stick-slip mitigation workbench: simulate rigs, see their modes, identify them from logs, "
                    "estimate the twist, and compare controllers.",
        epilog="Example: mitigate run scenarios/stick_slip_30rpm.toml --out out/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f"mitigate.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"mitigate.commands.{name}":
                continue
            raise
        mod.register(sub)
    return parser


#: the library speaks of its own arguments; the CLI names its flags
_WORDS = (("(pass force=True)", "(use --force)"), ("(pass overwrite=True)", "(use --force)"),
          ("jobs must be", "--jobs must be"), ("workers must be", "--workers must be"))


def cli_words(message: str) -> str:
    """A library message with its argument names replaced by the CLI's flags."""
    for a, b in _WORDS:
        message = message.replace(a, b)
    return message


class _Terminated(KeyboardInterrupt):
    """SIGTERM, turned into an exception so that ``finally`` blocks run (workers stopped, staged
    outputs removed)."""


def _on_sigterm(signum, frame):
    raise _Terminated()


def main(argv=None) -> int:
    global _json_wanted, _named_command
    words = sys.argv[1:] if argv is None else list(argv)
    _json_wanted = "--json" in words
    _named_command = next((w for w in words if w in COMMANDS), None)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:          # not the main thread (main() called from a thread): keep the default
        previous = None
    try:
        return _dispatch(args)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _dispatch(args) -> int:
    """Run the sub-command; every failure becomes one line and an exit code (module docstring)."""
    try:
        return int(args.func(args) or 0)
    except (ConfigError, DataError, SolverFailure) as exc:
        return _fail(args.command, "input", 2, f"mitigate {args.command}: error: {_line(cli_words(str(exc)))}")
    except PluginError as exc:
        return _fail(args.command, "plugin", 1, f"mitigate {args.command}: failed: {_line(str(exc))}")
    except KeyboardInterrupt as exc:
        kind = "terminated" if isinstance(exc, _Terminated) else "interrupted"
        return _fail(args.command, kind, 143 if kind == "terminated" else 130, f"mitigate {args.command}: {kind}")
    except BrokenPipeError:   # the reader went away (``mitigate modal --json | head``): not an error of ours
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 141
    except Exception as exc:  # an internal error: one line unless debugging
        if os.environ.get("MITIGATE_DEBUG"):
            raise
        return _fail(args.command, "internal", 1, f"mitigate {args.command}: internal error: {type(exc).__name__}: "
                                                   f"{_line(str(exc))} (set MITIGATE_DEBUG=1 for a traceback)")


def _line(text: str) -> str:
    """One line; a long one has its quoted values capped (models.errors.shorten, as the errors do)."""
    text = " ".join(text.split())
    return shorten(text) if len(text) > 4 * QUOTE_LIMIT else text


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
