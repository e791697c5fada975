"""The ``mitigate`` command line.

Each sub-command lives in ``mitigate/commands/<name>.py`` and exposes
``register(subparsers)``; the parser it adds sets ``func`` to a ``run(args) -> int``.
Bad input (``ConfigError``, ``DataError``) and solver failures become one line on
stderr and exit code 2; there is never a traceback for bad input.  A controller or
estimator that broke its contract outside a run (``PluginError``) is one line and exit 1;
inside ``run``/``benchmark`` it fails only its run, and the command exits 1.  Ctrl-C and
SIGTERM end the command cleanly (workers stopped, no half-written output), exit 130 / 143.
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


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message):  # noqa: D401
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        sys.exit(2)


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
        sys.stderr.write(f"mitigate {args.command}: error: {_line(cli_words(str(exc)))}\n")
        return 2
    except PluginError as exc:
        sys.stderr.write(f"mitigate {args.command}: failed: {_line(str(exc))}\n")
        return 1
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, _Terminated)
        sys.stderr.write(f"mitigate {args.command}: {'terminated' if terminated else 'interrupted'}\n")
        return 143 if terminated else 130
    except BrokenPipeError:   # the reader went away (``mitigate modal --json | head``): not an error of ours
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 141
    except Exception as exc:  # an internal error: one line unless debugging
        if os.environ.get("MITIGATE_DEBUG"):
            raise
        sys.stderr.write(f"mitigate {args.command}: internal error: {type(exc).__name__}: {_line(str(exc))} "
                         f"(set MITIGATE_DEBUG=1 for a traceback)\n")
        return 1


def _line(text: str) -> str:
    """One line; a long one has its quoted values capped (models.errors.shorten, as the errors do)."""
    text = " ".join(text.split())
    return shorten(text) if len(text) > 4 * QUOTE_LIMIT else text


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
