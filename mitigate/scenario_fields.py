"""The scenario file's limits and field converters (:mod:`mitigate.scenario` reads a file with them).

What a run may cost (samples, this machine's memory), the ``[control]`` section
(:class:`ControlSection`, parsed once by :func:`parse_control` and carried whole to the
controllers), quantities converted to SI, the tables and keys a section may hold, and
``[plant] max_speed``'s default.  Every error is one line naming the field (``where``).
"""

from __future__ import annotations

import math
import os
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from models.checks import finite_number
from models.errors import ConfigError, quote
from models.units import factor as unit_factor
from models.units import parse_quantity

__all__ = ["MAX_SAMPLES", "BYTES_PER_SAMPLE", "DEFAULT_TIMEOUT", "TIMEOUT_PERIODS", "MAX_CALL_TIME",
           "MAX_SPEED_FACTOR", "memory_bytes", "check_size", "table", "check_keys", "si_value", "call_time",
           "control_timing", "default_max_speed", "ControlSection", "parse_control"]

# A run keeps every sample in memory (states, measurements, estimates, actions: about 0.7 kB
# per sample and controller while it runs, measured on rig3 with the EKF), then hands it back
# for the logs and plots.  Both limits are checked before anything is allocated or run.
MAX_SAMPLES = 10_000_000
BYTES_PER_SAMPLE = 2048     # per sample and controller run, with room for the logs and plots
#: default per-call timeout of controllers and estimators [s]: at least this, and at least
#: TIMEOUT_PERIODS control periods (``[control] timeout``)
DEFAULT_TIMEOUT = 2.0
TIMEOUT_PERIODS = 100
#: the longest deadline, timeout or latency a scenario may give [s] (a day; longer is "off")
MAX_CALL_TIME = 86400.0

#: a body faster than this many times the largest programmed drive speed ends a run as diverged
#: (``[plant] max_speed``'s default: 100 rad/s on rig3's 30 rpm)
MAX_SPEED_FACTOR = 100.0 / math.pi


@dataclass(frozen=True)
class ControlSection:
    """The scenario's ``[control]`` section, parsed once (:func:`parse_control`) and carried whole
    from the scenario to the closed loop and the controllers (:class:`mitigate.controllers.base.ControlContext`).

    Attributes
    ----------
    start : the time the controllers act from [s] (before it, the programme alone)
    every : a controller is called every ``every`` DAQ samples (its call period is ``every dt``)
    deadline : the wall time a call may take [s] before its answer is a counted deadline miss and the
        fallback acts, or None
    timeout : the wall time after which a call that has not returned fails its run [s], or None
    latency : the delay [s] applied to each answer, or ``"measured"`` (the call's own wall time)
    speed : the target speed ``t -> [rad/s]`` of a drive whose input is not a speed (a torque drive's
        ``speed``, a profile), or None
    """

    start: float = 0.0
    every: int = 1
    deadline: float | None = None
    timeout: float | None = None
    latency: float | str = 0.0
    speed: Callable[[float], float] | None = None

    def period(self, dt: float) -> float:
        """The controllers' call period [s] for a DAQ period ``dt`` [s]."""
        return dt * self.every

    def replace(self, **changes) -> "ControlSection":
        """The section with ``changes`` (e.g. ``scenario.control.replace(start=5.0)``)."""
        return dataclasses.replace(self, **changes)


def parse_control(ctl: Mapping, model, dt: float, duration: float, where: str) -> ControlSection:
    """The :class:`ControlSection` of a scenario's ``[control]`` table (``where``: the file, for messages;
    ``dt``, ``duration`` [s]: the scenario's)."""
    from mitigate.profiles import parse_profile
    check_keys(ctl, {"start", "every", "deadline", "timeout", "latency", "speed"}, f"{where}: control")
    speed = None
    if "speed" in ctl:
        if model.drive.sets_speed:
            raise ConfigError(f"{where}: control.speed applies to a torque drive; rig {model.name!r} sets its speed "
                              f"through input {model.drive_input!r} (give it in [inputs])")
        speed = parse_profile(ctl["speed"], f"{where}: control.speed", duration, quantity="speed")
    start = finite_number(ctl.get("start", 0.0), f"{where}: control.start", nonneg=True, unit="s")
    if start >= duration:
        raise ConfigError(f"{where}: control.start must be < scenario.duration = {duration:g} s (the controllers "
                          f"would never act), got {start:g} s")
    every = ctl.get("every", 1)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError(f"{where}: control.every must be an integer >= 1, got {quote(every)}")
    deadline, timeout, latency = control_timing(ctl, dt * every, f"{where}: control")
    return ControlSection(start, every, deadline, timeout, latency, speed)


def default_max_speed(model, inputs, control_speed, duration: float) -> float:
    """``[plant] max_speed``'s default [rad/s]: MAX_SPEED_FACTOR times the largest drive speed the
    scenario programmes (a torque drive: its ``[control] speed``, else the rig's nominal speed)."""
    ts = np.linspace(0.0, duration, 201)
    if model.drive.sets_speed:
        w = max(abs(float(inputs[model.drive_input](t))) for t in ts)
    elif control_speed is not None:
        w = max(abs(float(control_speed(t))) for t in ts)
    else:
        w = 0.0
    w = max(w, abs(model.nominal_speed()))
    return MAX_SPEED_FACTOR * w if w > 0 else 100.0


def table(data: Mapping, key: str, where: str) -> Mapping:
    v = data.get(key, {})
    if not isinstance(v, Mapping):
        raise ConfigError(f"{where}: {key} must be a table, got {type(v).__name__}")
    return v


def check_keys(tab: Mapping, allowed, where: str):
    for k in tab:
        if k not in allowed:
            raise ConfigError(f"{where}.{k}: unknown key; expected one of {', '.join(sorted(allowed))}")


def memory_bytes() -> int | None:
    """This machine's physical memory, or its cgroup's limit if lower (None: unknown)."""
    total = None
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        pass
    for f in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            limit = int(Path(f).read_text().split()[0])
        except (OSError, ValueError, IndexError):   # absent, or "max" (no limit)
            continue
        if limit > 0:
            total = limit if total is None else min(total, limit)
    return total if total and total > 0 else None


def check_size(duration: float, dt: float, runs: int, where: str) -> None:
    """One-line ConfigError if ``duration / dt`` samples cannot be run (count, then memory)."""
    samples = duration / dt
    shown = f"{samples:,.0f}" if samples < 1e15 else f"{samples:.3g}"
    head = f"{where}: scenario.duration / scenario.dt = {duration:g} s / {dt:g} s = {shown} samples"
    if samples > MAX_SAMPLES:
        raise ConfigError(f"{head}; the limit is {MAX_SAMPLES:,} samples (shorten the duration or raise dt)")
    need, have = samples * runs * BYTES_PER_SAMPLE, memory_bytes()
    if have is not None and need > have:
        fit = int(have // (runs * BYTES_PER_SAMPLE))
        raise ConfigError(f"{head}; the limit is {fit:,} samples here: {runs} controller run(s) need about "
                          f"{need / 2**30:.1f} GiB ({BYTES_PER_SAMPLE} bytes per sample each), this machine has "
                          f"{have / 2**30:.1f} GiB of memory")


def si_value(v: Any, kind: str, where: str) -> float:
    """A number (SI) or a quantity string converted to SI."""
    if isinstance(v, str):
        q = parse_quantity(v)
        if q is None:
            raise ConfigError(f"{where} must be a number or a quantity such as \"1.5 N m\", got {v!r}")
        return q[0] * unit_factor(q[1] or "-", kind, where)
    return finite_number(v, where)


def call_time(v: Any, where: str) -> float:
    """A positive time [s] of at most a day: a number or a quantity such as ``"5 ms"``."""
    t = si_value(v, "time", where)
    if not 0 < t <= MAX_CALL_TIME:
        raise ConfigError(f"{where} must be > 0 s and at most {MAX_CALL_TIME:g} s (or \"off\"), got {quote(v)}")
    return t


def control_timing(ctl: Mapping, period: float, where: str) -> tuple[float | None, float | None, float | str]:
    """``(deadline, timeout, latency)`` of the ``[control]`` table (:mod:`mitigate.scenario`'s docstring): deadline None
    unless given; timeout default ``max(DEFAULT_TIMEOUT, TIMEOUT_PERIODS x period)``, "off" for none;
    latency 0, a fixed time [s], or "measured"."""
    d = ctl.get("deadline", "off")
    deadline = None if d == "off" else period if d == "period" else call_time(d, f"{where}.deadline")
    tv = ctl.get("timeout")
    if tv == "off":
        timeout = None
    elif tv is None:
        timeout = max(DEFAULT_TIMEOUT, TIMEOUT_PERIODS * period)
    else:
        timeout = call_time(tv, f"{where}.timeout")
    if deadline is not None and timeout is not None and timeout < deadline:
        raise ConfigError(f"{where}.timeout must be >= control.deadline = {deadline:g} s, got {timeout:g} s")
    lv = ctl.get("latency", 0.0)
    if lv == "measured":
        return deadline, timeout, "measured"
    bad = f"{where}.latency must be \"measured\" or a time >= 0 such as \"3 ms\", got {quote(lv)}"
    try:
        latency = si_value(lv, "time", f"{where}.latency")
    except ConfigError:
        raise ConfigError(bad) from None
    if not 0 <= latency <= MAX_CALL_TIME:
        raise ConfigError(bad)
    return deadline, timeout, latency
