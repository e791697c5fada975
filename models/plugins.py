"""Plug-ins: how controllers and estimators, built-in or your own, are found, built and called.

One factory shape for every pluggable kind (issue 19): a ``kind`` is

- a built-in name of the family's registry (``{"pi": "mitigate.controllers.pi:PIOnly", ...}``),
- the name of an entry point of the family's group (``stickslip.controllers``,
  ``stickslip.estimators``: a package that registers its own), or
- ``"module:Class"``: any importable subclass of the family's base class, loaded with
  :mod:`importlib` (never ``eval``).

Importing a module runs its top-level code: **a scenario file that names ``module:Class`` runs
that module's code, so it is code you trust** (as a Python script is).

Calling plug-in code is guarded (:func:`call`): the rule between a transient failure and a
failed run is

- :class:`models.errors.SolverFailure` raised inside ``_step_impl`` / ``_update_impl`` is the
  one transient failure: the plug-in's documented fallback answers it and it is counted;
- anything else -- any other exception, ``SystemExit``, a non-finite or wrongly typed result, a
  call that does not return within its ``timeout`` -- is a :class:`models.errors.PluginError`
  naming the exception's type and first line: its run is FAILED (the other runs go on).
  ``KeyboardInterrupt`` is never swallowed (Ctrl-C ends the command).

The ``timeout`` is enforced with ``SIGALRM`` when the call runs in a process's main thread (the
worker processes of ``mitigate run``, ``sweep`` and ``benchmark``, and the CLI itself): a call
still running then is interrupted (``time.sleep``, Python loops; C code that never returns to
Python is stopped by the worker pool's watchdog instead, :mod:`mitigate.workers`).  A closed loop
runs under :func:`watchdog` (one periodic alarm for the whole run: a timer per call cost about
8 us, 7 % of a PI run); elsewhere each call arms a one-shot timer.  Outside the main thread the
call is timed and a late return fails the same way.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import re
import signal
import threading
import time
from typing import Any, Callable, Mapping

from models.errors import ConfigError, PluginError, SolverFailure

__all__ = ["load_class", "construct", "construction_timeout", "call", "watchdog", "describe", "StepTimeout",
           "CONSTRUCT_FACTOR"]

_REF = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


def describe(exc: BaseException) -> str:
    """``"KeyError: 'motor_torque'"``: the exception's type and the first line of its message."""
    text = str(exc).strip().splitlines()
    first = text[0] if text else ""
    if isinstance(exc, SystemExit):
        first = f"exit code {exc.code!r}" if exc.code is not None else "no exit code"
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def _import(ref: str, where: str) -> Any:
    mod_name, _, attr = ref.partition(":")
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        if exc.name and (mod_name == exc.name or mod_name.startswith(exc.name + ".")):
            raise ConfigError(f"{where}.kind: module {mod_name!r} not found (is it installed or on PYTHONPATH?)") from None
        raise ConfigError(f"{where}.kind: module {mod_name!r} could not be imported: {describe(exc)}") from None
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # noqa: BLE001 - a user's module may fail in any way (even sys.exit); one line
        raise ConfigError(f"{where}.kind: module {mod_name!r} could not be imported: {describe(exc)}") from None
    obj = getattr(mod, attr, None)
    if obj is None:
        raise ConfigError(f"{where}.kind: module {mod_name!r} has no {attr!r}")
    return obj


def _check_class(obj, base: type, label: str, where: str) -> type:
    if not (isinstance(obj, type) and issubclass(obj, base)):
        raise ConfigError(f"{where}.kind: {label} is not a {base.__name__} subclass ({base.__module__}.{base.__name__})")
    if inspect.isabstract(obj):
        missing = ", ".join(sorted(getattr(obj, "__abstractmethods__", ()))) or "?"
        raise ConfigError(f"{where}.kind: {label} is abstract: it does not implement {missing}")
    return obj


def construction_timeout(kind: Any, registry: Mapping[str, str], timeout: float | None) -> float | None:
    """How long a plug-in's constructor may take [s]: built-in kinds are not timed (the NMPC may
    compile C for minutes on a cold cache); a user's (``module:Class``, entry point) gets
    ``CONSTRUCT_FACTOR`` per-call timeouts (60 s by default)."""
    if timeout is None or (isinstance(kind, str) and kind in registry):
        return None
    return CONSTRUCT_FACTOR * timeout


#: a user plug-in's constructor may take this many per-call timeouts
CONSTRUCT_FACTOR = 30


def load_class(kind: Any, *, registry: Mapping[str, str], group: str, base: type, where: str) -> type:
    """The class of a ``kind``: a built-in of ``registry`` (name -> ``"module:Class"``), an entry
    point of ``group``, or ``"module:Class"``.

    Raises
    ------
    ConfigError : one line naming ``<where>.kind``: unknown kind, a module that is missing or
        fails to import, a name that is not a concrete ``base`` subclass.
    """
    if not isinstance(kind, str) or not kind:
        raise ConfigError(f"{where}.kind must be a {base.__name__} kind (a string), got {kind!r}")
    if kind in registry:
        return _check_class(_import(registry[kind], where), base, repr(registry[kind]), where)
    if _REF.match(kind):
        return _check_class(_import(kind, where), base, repr(kind), where)
    from importlib.metadata import entry_points
    for ep in entry_points(group=group):
        if ep.name == kind:
            try:
                obj = ep.load()
            except KeyboardInterrupt:
                raise
            except BaseException as exc:  # noqa: BLE001 - as for module:Class
                raise ConfigError(f"{where}.kind: entry point {kind!r} could not be loaded: {describe(exc)}") from None
            return _check_class(obj, base, f"entry point {kind!r}", where)
    raise ConfigError(f"{where}.kind must be one of {', '.join(registry)}, a registered '{group}' entry point "
                      f"or 'module:Class', got {kind!r}")


def construct(cls: type, options: Any, context: Any, where: str, timeout: float | None = None):
    """``cls(options, context)``: a ConfigError from the constructor stays a ConfigError (bad
    input, prefixed with ``where``); anything else -- also not returning within ``timeout`` [s] --
    is a :class:`PluginError` (a broken plug-in)."""
    try:
        return call(cls, options, context, timeout=timeout, what=f"{cls.__name__}(options, context)")
    except PluginError as exc:
        if isinstance(exc.__cause__, ConfigError):
            msg = str(exc.__cause__)
            raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None
        if str(exc).startswith("TimeoutError"):
            raise
        raise PluginError(f"{cls.__name__}(options, context) failed: {exc}") from exc.__cause__
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # noqa: BLE001 - a plug-in's constructor may fail in any way
        raise PluginError(f"{cls.__name__}(options, context) failed: {describe(exc)}") from exc


class StepTimeout(BaseException):
    """Raised inside a plug-in call that ran past its timeout (a BaseException so that a
    plug-in's ``except Exception`` does not swallow it)."""


_armed = threading.local()            # .on: a call is armed; .until: its deadline (perf_counter) under a watchdog
_previous = {"handler": None}          # SIGALRM's handler before ours, called for alarms that are not ours
_watch = {"on": False}                 # a periodic watchdog runs (:func:`watchdog`)


def _on_alarm(signum, frame):
    if getattr(_armed, "on", False):
        until = getattr(_armed, "until", None)
        if until is None or time.perf_counter() > until:     # a one-shot alarm, or the watchdog's tick past it
            raise StepTimeout()
        return
    if _watch["on"]:
        return                          # a watchdog tick between calls
    prev = _previous["handler"]
    if callable(prev):
        prev(signum, frame)


def _install() -> None:
    if signal.getsignal(signal.SIGALRM) is not _on_alarm:
        _previous["handler"] = signal.signal(signal.SIGALRM, _on_alarm)
        signal.siginterrupt(signal.SIGALRM, False)     # C code's system calls restart after a tick


@contextlib.contextmanager
def watchdog(timeout: float | None):
    """Around many guarded calls (a closed loop): one periodic SIGALRM every ``timeout / 4`` (at
    most 0.25 s) instead of arming a timer per call; a call past its deadline is interrupted at
    the next tick.  Outside the main thread, or with ``timeout`` None, it does nothing."""
    if timeout is None or _watch["on"] or threading.current_thread() is not threading.main_thread():
        yield
        return
    tick = min(0.25, timeout / 4)
    try:
        _install()
        signal.setitimer(signal.ITIMER_REAL, tick, tick)
    except (ValueError, OSError, AttributeError, OverflowError):
        yield
        return
    _watch["on"] = True
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        _watch["on"] = False


def _arm(timeout: float | None) -> bool:
    """Arm this call's timeout if this is the main thread and no outer call armed it: under a
    :func:`watchdog` by noting its deadline (no system call), else with a one-shot ``setitimer``."""
    if timeout is None or getattr(_armed, "on", False) or threading.current_thread() is not threading.main_thread():
        return False
    if _watch["on"]:
        _armed.until = time.perf_counter() + timeout
        _armed.on = True
        return True
    try:
        _install()
        signal.setitimer(signal.ITIMER_REAL, timeout)
    except (ValueError, OSError, AttributeError, OverflowError):   # no SIGALRM here (not POSIX, embedded)
        return False
    _armed.until = None
    _armed.on = True
    return True


def _disarm() -> None:
    _armed.on = False
    if not _watch["on"]:
        signal.setitimer(signal.ITIMER_REAL, 0)


def call(fn: Callable, *args, timeout: float | None = None, what: str = "call"):
    """``fn(*args)`` under the rule of the module docstring.

    Returns ``fn``'s result; re-raises :class:`SolverFailure` (the caller's fallback answers it)
    and ``KeyboardInterrupt``; raises :class:`PluginError` for every other exception (also
    ``SystemExit``) and for a call that did not return within ``timeout`` [s]
    (``"TimeoutError: step did not return within 2 s"``).
    """
    armed = _arm(timeout)
    t0 = time.perf_counter()
    try:
        try:
            out = fn(*args)
        finally:
            if armed:
                _disarm()
    except (SolverFailure, KeyboardInterrupt, PluginError):
        raise
    except StepTimeout:
        raise PluginError(f"TimeoutError: {what} did not return within {timeout:g} s") from None
    except BaseException as exc:  # noqa: BLE001 - the rule: anything else fails the run, with its reason
        raise PluginError(describe(exc)) from exc
    took = time.perf_counter() - t0
    if timeout is not None and took > timeout:
        raise PluginError(f"TimeoutError: {what} did not return within {timeout:g} s (it took {took:.3g} s)")
    return out
