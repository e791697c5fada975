"""Input programmes of a scenario: constant, steps, ramps and random "formation" changes.

A profile is a TOML table::

    n1 = { kind = "constant", value = 20.0 }                          # N
    n1 = { kind = "steps", times = [0, 20, 40], values = [15, 25, 20] }
    n1 = { kind = "ramp", t0 = 10, t1 = 50, v0 = 10, v1 = 35 }
    n1 = { kind = "random", mean = 20, std = 4, hold = 5, min = 5, max = 40, seed = 3 }
    omega_ref = { kind = "constant", value = 30, unit = "rpm" }       # rpm -> rad/s

Random profiles are piecewise-constant levels redrawn every ``hold`` seconds from a
seeded generator, clipped to [min, max].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from models.errors import ConfigError
from models.checks import finite_number as _num

__all__ = ["Profile", "parse_profile"]

_UNITS = {"": 1.0, "si": 1.0, "rad/s": 1.0, "N": 1.0, "N m": 1.0, "rpm": 2 * math.pi / 60, "kN": 1e3}
_KEYS = {
    "constant": {"value"},
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
        if self.kind == "ramp":
            t0, t1 = self.times
            v0, v1 = self.values
            if t <= t0:
                return v0
            if t >= t1:
                return v1
            return v0 + (v1 - v0) * (t - t0) / (t1 - t0)
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        return self.values[max(i, 0)]

    def scaled(self, factor: float) -> "Profile":
        return Profile(self.kind, self.times, tuple(v * factor for v in self.values))

    def with_value(self, value: float) -> "Profile":
        """The constant profile at ``value`` (used by sweeps to replace a field)."""
        return Profile("constant", (0.0,), (float(value),))


def parse_profile(spec: Any, where: str, duration: float, *, nonnegative: bool = False) -> Profile:
    """Validate a TOML profile table and return a :class:`Profile` in SI units."""
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        spec = {"kind": "constant", "value": spec}
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where} must be a number or a table with 'kind', got {spec!r}")
    kind = spec.get("kind")
    if kind not in _KEYS:
        raise ConfigError(f"{where}.kind must be one of {', '.join(_KEYS)}, got {kind!r}")
    allowed = _KEYS[kind] | {"kind", "unit"}
    for key in spec:
        if key not in allowed:
            raise ConfigError(f"{where}.{key}: unknown key for kind {kind!r}; expected one of {', '.join(sorted(allowed))}")
    required = _KEYS[kind] - ({"min", "max", "seed"} if kind == "random" else set())
    for key in sorted(required):
        if key not in spec:
            raise ConfigError(f"{where}: missing field {key!r} for kind {kind!r}")
    unit = spec.get("unit", "")
    if unit not in _UNITS:
        raise ConfigError(f"{where}.unit must be one of {', '.join(u for u in _UNITS if u)}, got {unit!r}")
    f = _UNITS[unit]
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
