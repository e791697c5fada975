"""Input programmes of a scenario: constant, steps, ramps and random "formation" changes.

A profile is a TOML table::

    n1 = { kind = "constant", value = 20.0 }                          # N
    n1 = { kind = "steps", times = [0, 20, 40], values = [15, 25, 20] }
    n1 = { kind = "ramp", t0 = 10, t1 = 50, v0 = 10, v1 = 35 }
    n1 = { kind = "random", mean = 20, std = 4, hold = 5, min = 5, max = 40, seed = 3 }
    n1 = { kind = "sine", mean = 20, amplitude = 3, period = 2.0 }     # period [s], phase [rad]
    omega_ref = { kind = "constant", value = 30, unit = "rpm" }       # rpm -> rad/s
    omega_ref = "30 rpm"                                              # a constant, as a quantity
    omega_top = { kind = "log", file = "run1.csv", channel = "omega_top" }   # replayed, interpolated

Values are in ``unit`` (any unit of the input's quantity, :mod:`models.units`; SI if absent).
Random profiles are piecewise-constant levels redrawn every ``hold`` seconds from a seeded
generator, clipped to [min, max].  A ``log`` profile replays a channel of a CSV log (a path
relative to the scenario file), interpolated linearly and held at its ends.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from models.errors import ConfigError, DataError
from models.checks import finite_number as _num
from models.units import factor as unit_factor

__all__ = ["Profile", "parse_profile"]

_KEYS = {
    "constant": {"value"},
    "sine": {"mean", "amplitude", "period", "phase"},
    "log": {"file", "channel"},
    "steps": {"times", "values"},
    "ramp": {"t0", "t1", "v0", "v1"},
    "random": {"mean", "std", "hold", "min", "max", "seed"},
}


@dataclass(frozen=True)
class Profile:
    """A scalar input programme ``value(t)``, in SI units."""

    kind: str
    times: tuple[float, ...]
    values: tuple[float, ...]

    def __call__(self, t: float) -> float:
        if self.kind == "constant":
            return self.values[0]
        if self.kind == "sine":
            mean, amp, period, phase = self.values
            return mean + amp * math.sin(2 * math.pi * t / period + phase)
        if self.kind == "log":
            return float(np.interp(t, self.times, self.values))
        if self.kind == "ramp":
            t0, t1 = self.times
            v0, v1 = self.values
            if t <= t0:
                return v0
            if t >= t1:
                return v1
            return v0 + (v1 - v0) * (t - t0) / (t1 - t0)
        i = bisect.bisect_right(self.times, t) - 1      # np.searchsorted(..., side="right") - 1, on a tuple
        return self.values[max(i, 0)]

    def scaled(self, factor: float) -> "Profile":
        if self.kind == "sine":
            mean, amp, period, phase = self.values
            return Profile(self.kind, self.times, (mean * factor, amp * factor, period, phase))
        return Profile(self.kind, self.times, tuple(v * factor for v in self.values))

    def extremes(self) -> tuple[float, float]:
        """Smallest and largest value the profile takes [SI]."""
        if self.kind == "sine":
            mean, amp, _, _ = self.values
            return mean - abs(amp), mean + abs(amp)
        return min(self.values), max(self.values)

    def with_value(self, value: float) -> "Profile":
        """The constant profile at ``value`` (used by sweeps to replace a field)."""
        return Profile("constant", (0.0,), (float(value),))


def parse_profile(spec: Any, where: str, duration: float, *, quantity: str = "dimensionless",
                  nonnegative: bool = False, base=None) -> Profile:
    """Validate a TOML profile (a number, a quantity string or a table) and return a
    :class:`Profile` in SI units; ``quantity`` is the input's kind ("speed", "force", ...) and
    ``base`` the folder relative to which a ``log`` profile's file is found."""
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        spec = {"kind": "constant", "value": spec}
    elif isinstance(spec, str):
        from models.units import parse_quantity
        q = parse_quantity(spec)
        if q is None:
            raise ConfigError(f"{where} must be a number, a quantity such as \"30 rpm\" or a table with 'kind', "
                              f"got {spec!r}")
        spec = {"kind": "constant", "value": q[0], "unit": q[1]}
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where} must be a number or a table with 'kind', got {spec!r}")
    kind = spec.get("kind")
    if kind not in _KEYS:
        raise ConfigError(f"{where}.kind must be one of {', '.join(_KEYS)}, got {kind!r}")
    allowed = _KEYS[kind] | {"kind", "unit"}
    for key in spec:
        if key not in allowed:
            raise ConfigError(f"{where}.{key}: unknown key for kind {kind!r}; expected one of {', '.join(sorted(allowed))}")
    required = _KEYS[kind] - ({"min", "max", "seed"} if kind == "random" else set()) - ({"phase"} if kind == "sine" else set())
    for key in sorted(required):
        if key not in spec:
            raise ConfigError(f"{where}: missing field {key!r} for kind {kind!r}")
    unit = spec.get("unit", "")
    if not isinstance(unit, str):
        raise ConfigError(f"{where}.unit must be a unit string, got {unit!r}")
    f = unit_factor(unit or "-", quantity, f"{where}.unit") if unit else 1.0
    if kind == "sine":
        mean, amp, period = (_num(spec[k], f"{where}.{k}") for k in ("mean", "amplitude", "period"))
        if not period > 0:
            raise ConfigError(f"{where}.period must be > 0 s, got {period}")
        phase = _num(spec.get("phase", 0.0), f"{where}.phase")
        prof = Profile(kind, (), (mean * f, amp * f, period, phase))
        if nonnegative and prof.extremes()[0] < 0:
            raise ConfigError(f"{where} must be >= 0, but mean - amplitude = {prof.extremes()[0]:g}")
        return prof
    if kind == "log":
        from pathlib import Path
        from models.logs import read_csv
        fpath = Path(str(spec["file"]))
        if not fpath.is_absolute() and base is not None:
            fpath = Path(base) / fpath
        try:
            lg = read_csv(fpath, required=(str(spec["channel"]),))
        except DataError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        if unit:
            raise ConfigError(f"{where}.unit: a log profile takes the log's own unit")
        vals = np.asarray(lg[str(spec["channel"])], float)
        prof = Profile(kind, tuple(float(t) for t in lg.t), tuple(float(v) for v in vals))
        if nonnegative and min(prof.values) < 0:
            raise ConfigError(f"{where} must be >= 0, got a value of {min(prof.values)}")
        return prof
    if kind == "constant":
        prof = Profile(kind, (0.0,), (_num(spec["value"], f"{where}.value") * f,))
    elif kind == "steps":
        ts, vs = spec["times"], spec["values"]
        if not isinstance(ts, list) or not isinstance(vs, list) or len(ts) != len(vs) or not ts:
            raise ConfigError(f"{where}: times and values must be non-empty lists of equal length, "
                              f"got {len(ts) if isinstance(ts, list) else ts!r} and {len(vs) if isinstance(vs, list) else vs!r}")
        tt = [_num(v, f"{where}.times[{i}]") for i, v in enumerate(ts)]
        if any(b <= a for a, b in zip(tt, tt[1:])):
            raise ConfigError(f"{where}.times must be strictly increasing, got {tt}")
        prof = Profile(kind, tuple(tt), tuple(_num(v, f"{where}.values[{i}]") * f for i, v in enumerate(vs)))
    elif kind == "ramp":
        t0, t1 = _num(spec["t0"], f"{where}.t0"), _num(spec["t1"], f"{where}.t1")
        if not t1 > t0:
            raise ConfigError(f"{where}: t1 must be > t0, got t0={t0}, t1={t1}")
        prof = Profile(kind, (t0, t1), (_num(spec["v0"], f"{where}.v0") * f, _num(spec["v1"], f"{where}.v1") * f))
    else:
        mean, std, hold = (_num(spec[k], f"{where}.{k}") for k in ("mean", "std", "hold"))
        if std < 0 or hold <= 0:
            raise ConfigError(f"{where}: std must be >= 0 and hold > 0 s, got std={std}, hold={hold}")
        lo = _num(spec.get("min", -math.inf if not nonnegative else 0.0), f"{where}.min") if "min" in spec else (0.0 if nonnegative else -math.inf)
        hi = _num(spec["max"], f"{where}.max") if "max" in spec else math.inf
        if not lo < hi:
            raise ConfigError(f"{where}: min must be < max, got [{lo}, {hi}]")
        seed = spec.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ConfigError(f"{where}.seed must be an integer, got {seed!r}")
        rng = np.random.default_rng(seed)
        n = max(1, int(math.ceil(duration / hold)) + 1)
        levels = np.clip(mean + std * rng.standard_normal(n), lo, hi) * f
        prof = Profile(kind, tuple(float(i * hold) for i in range(n)), tuple(float(v) for v in levels))
    if nonnegative and min(prof.values) < 0:
        raise ConfigError(f"{where} must be >= 0, got a value of {min(prof.values)}")
    return prof
