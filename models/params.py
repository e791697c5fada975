"""Parameter sets: named, unit-carrying values with bounds and provenance.

A rig file (:mod:`models.rig`) declares its parameters; :meth:`models.rig.RigModel.published`
gives them as a frozen :class:`ParameterSet`.  A set loads from and saves to TOML, so a
fitted set can replace the published one in every command::

    model = "rig3"           # a shipped rig's name, or the path of a rig file
    base = "published"       # optional: fill missing fields from the rig file

    [params]
    k1 = 1.1175              # SI units (N m/rad), or a quantity string "1.1175 N m/rad"

    [bounds]                 # optional: fitting bounds, [lower, upper] (SI)
    k1 = [0.5, 2.0]

    [stderr]                 # optional: written by `mitigate identify`
    k1 = 0.004

Values are accessed by name, ``p["k1"]`` or ``p.k1``; :meth:`ParameterSet.vector` gives
them in the rig's order.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from models.errors import ConfigError
from models.checks import read_toml
from models.units import parse_quantity

__all__ = ["Spec", "ParameterSet", "LEADSCREW_FINE_TUNED"]


@dataclass(frozen=True)
class Spec:
    """Metadata of one parameter: SI unit, physical bounds, provenance, quantity kind."""

    unit: str
    lower: float
    upper: float
    source: str
    doc: str = ""
    positive: bool = False  # strict lower bound (> lower) instead of >=
    kind: str = ""


class ParameterSet:
    """A frozen set of named floats in SI units (see module docstring).

    Parameters
    ----------
    model : the rig's name (or rig-file path) the set belongs to
    specs : ``{name: Spec}`` in the rig's order
    values : ``{name: value}`` for every name of ``specs``
    fit_bounds : ``((name, lower, upper), ...)``: fitting bounds that replace the physical ones
    stderr : ``((name, standard error), ...)``
    where : the file or table the values came from, opening every message (``"f.toml: params.k1
        ..."``; default: none)

    Raises
    ------
    ConfigError : a value that is not a finite number within its physical bounds
        (``"params.k1 must be in [0, 1000] N m/rad, got -1"``; the rig is not in the field name, which
        stays readable when the rig is a file path).
    """

    __slots__ = ("model", "_specs", "_values", "fit_bounds", "stderr")

    def __init__(self, model: str, specs: Mapping[str, Spec], values: Mapping[str, float], *,
                 fit_bounds: Iterable[tuple[str, float, float]] = (), stderr: Iterable[tuple[str, float]] = (),
                 where: str = ""):
        head = f"{where}: " if where else ""
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "_specs", dict(specs))
        vals = {}
        for name, spec in self._specs.items():
            if name not in values:
                raise ConfigError(f"{head}params.{model}: missing value of {name!r}")
            vals[name] = self._check(name, spec, values[name], f"{head}params.{name}")
        for name in values:
            if name not in self._specs:
                raise ConfigError(f"{head}params.{model}.{name}: unknown parameter; expected one of {', '.join(self._specs)}")
        object.__setattr__(self, "_values", vals)
        fb = tuple((str(n), float(lo), float(hi)) for n, lo, hi in fit_bounds)
        for name, lo, hi in fb:
            if name not in self._specs:
                raise ConfigError(f"{head}bounds.{name}: unknown parameter of {model}; expected one of "
                                  f"{', '.join(self._specs)}")
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise ConfigError(f"{head}bounds.{name} must be finite, got [{lo}, {hi}]")
            if not lo < hi:
                raise ConfigError(f"{head}bounds.{name} must be [lower, upper] with lower < upper, got [{lo:g}, {hi:g}]")
        object.__setattr__(self, "fit_bounds", fb)
        object.__setattr__(self, "stderr", tuple((str(n), float(s)) for n, s in stderr))

    @staticmethod
    def _check(name: str, spec: Spec, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise ConfigError(f"{where} must be a number [{spec.unit}], got {value!r} ({type(value).__name__})")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{where} must be finite [{spec.unit}], got {value}")
        if spec.positive and not value > spec.lower:
            raise ConfigError(f"{where} must be > {spec.lower:g} {spec.unit}, got {value:g}")
        if value < spec.lower or value > spec.upper:
            raise ConfigError(f"{where} must be in [{spec.lower:g}, {spec.upper:g}] {spec.unit}, got {value:g}")
        return value

    # ------------------------------------------------------------------ immutability, access
    def __setattr__(self, key, value):
        raise AttributeError(f"ParameterSet is frozen; use .replace({key}=...)")

    def __getattr__(self, name: str) -> float:
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(f"{self.model}: no parameter {name!r}") from None

    def __getitem__(self, name: str) -> float:
        return self._known(self._values, name)

    def __contains__(self, name: str) -> bool:
        return name in self._values

    def __eq__(self, other) -> bool:
        return isinstance(other, ParameterSet) and self.model == other.model and self._values == other._values

    def __hash__(self) -> int:
        return hash((self.model, tuple(self._values.items())))

    def __repr__(self) -> str:
        body = ", ".join(f"{k}={v:g}" for k, v in list(self._values.items())[:6])
        more = ", ..." if len(self._values) > 6 else ""
        return f"ParameterSet({self.model!r}: {body}{more})"

    def __reduce__(self):
        return (_rebuild, (self.model, self._specs, self._values, self.fit_bounds, self.stderr))

    # ------------------------------------------------------------------ structure
    def names(self) -> tuple[str, ...]:
        """Parameter names in the rig's order (the order of :meth:`vector`)."""
        return tuple(self._specs)

    def spec(self, name: str) -> Spec:
        return self._known(self._specs, name)

    def _known(self, table: dict, name: str):
        """``table[name]`` of a parameter table; ConfigError naming the rig's parameters if unknown."""
        try:
            return table[name]
        except KeyError:
            raise ConfigError(f"{self.model}: unknown parameter {name!r}; expected one of {', '.join(self._specs)}") from None

    @property
    def specs(self) -> dict[str, Spec]:
        return dict(self._specs)

    def as_dict(self) -> dict[str, float]:
        return dict(self._values)

    def vector(self, names: Iterable[str] | None = None) -> np.ndarray:
        """Values as a float array, in :meth:`names` order unless ``names`` is given."""
        return np.array([self[n] for n in (names if names is not None else self._specs)], dtype=float)

    def replace(self, **changes: float) -> "ParameterSet":
        """A copy with some values changed (validated); bounds and standard errors are kept."""
        for n in changes:
            self.spec(n)
        vals = dict(self._values)
        vals.update(changes)
        return ParameterSet(self.model, self._specs, vals, fit_bounds=self.fit_bounds, stderr=self.stderr)

    def with_vector(self, names, values) -> "ParameterSet":
        return self.replace(**{n: float(v) for n, v in zip(names, values)})

    def with_meta(self, *, fit_bounds=None, stderr=None) -> "ParameterSet":
        """A copy with other fitting bounds and/or standard errors."""
        return ParameterSet(self.model, self._specs, self._values,
                            fit_bounds=self.fit_bounds if fit_bounds is None else fit_bounds,
                            stderr=self.stderr if stderr is None else stderr)

    def bounds(self, name: str) -> tuple[float, float]:
        """Fitting bounds of a parameter: the user's ``[bounds]`` if given, else physical bounds."""
        for n, lo, hi in self.fit_bounds:
            if n == name:
                return lo, hi
        spec = self.spec(name)
        lo = spec.lower
        if spec.positive:
            lo = spec.lower + max(1e-12, 1e-9 * abs(self[name]))
        return lo, spec.upper

    def stderr_of(self, name: str) -> float | None:
        for n, s in self.stderr:
            if n == name:
                return s
        return None

    def table(self) -> list[tuple[str, float, str, str]]:
        """(name, value, unit, source) rows for printing."""
        return [(n, self[n], s.unit, s.source) for n, s in self._specs.items()]

    # ------------------------------------------------------------------ TOML
    def from_mapping(self, data: Mapping[str, Any], where: str = "parameter table") -> "ParameterSet":
        """A set of the same rig built from a TOML-like mapping (module docstring); missing
        values come from this set when ``base = "published"``."""
        from models.units import factor

        if not isinstance(data, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(data).__name__}")
        allowed = {"model", "base", "params", "bounds", "stderr", "provenance"}
        for key in data:
            if key not in allowed:
                raise ConfigError(f"{where}: {key}: unknown key; expected one of {', '.join(sorted(allowed))}")
        values = data.get("params", {})
        if not isinstance(values, Mapping):
            raise ConfigError(f"{where}: params must be a table, got {type(values).__name__}")
        base = data.get("base")
        if base not in (None, "published"):
            raise ConfigError(f"{where}: base must be \"published\" or absent, got {base!r}")
        out: dict[str, Any] = {}
        for key, v in values.items():
            if key not in self._specs:
                raise ConfigError(f"{where}: params.{key}: unknown parameter for model {self.model!r}; "
                                  f"expected one of {', '.join(self._specs)}")
            if isinstance(v, str):
                q = parse_quantity(v)
                if q is None or not self._specs[key].kind:
                    raise ConfigError(f"{where}: params.{key} must be a number [{self._specs[key].unit}] or a quantity "
                                      f"string such as \"1.5 {self._specs[key].unit}\", got {v!r}")
                v = q[0] * factor(q[1] or "-", self._specs[key].kind, f"{where}: params.{key}")
            out[key] = v
        if base is None:
            missing = [n for n in self._specs if n not in out]
            if missing:
                raise ConfigError(f"{where}: params: missing field(s) {', '.join(missing)} for model {self.model!r} "
                                  f"(give them, or set base = \"published\")")
        vals = dict(self._values)
        vals.update(out)
        bounds = []
        for key, b in dict(data.get("bounds", {})).items():
            if key not in self._specs:
                raise ConfigError(f"{where}: bounds.{key}: unknown parameter for model {self.model!r}")
            if not (isinstance(b, list) and len(b) == 2 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in b)):
                raise ConfigError(f"{where}: bounds.{key} must be [lower, upper] numbers, got {b!r}")
            bounds.append((key, float(b[0]), float(b[1])))
        stderr = []
        for key, s in dict(data.get("stderr", {})).items():
            if key not in self._specs:
                raise ConfigError(f"{where}: stderr.{key}: unknown parameter for model {self.model!r}")
            if not isinstance(s, (int, float)) or isinstance(s, bool) or not math.isfinite(s) or s < 0:
                raise ConfigError(f"{where}: stderr.{key} must be a finite number >= 0, got {s!r}")
            stderr.append((key, float(s)))
        return ParameterSet(self.model, self._specs, vals, fit_bounds=bounds, stderr=stderr, where=where)

    def to_toml_string(self, note: str = "", base: str | os.PathLike | None = None) -> str:
        """The set as TOML; ``base``: the folder the file goes to, which a rig file's path is written
        relative to (a parameter file that names its rig by an absolute path breaks when the folder
        moves; :func:`models.rig.load_params` takes a relative path from the parameter file's folder)."""
        model = self.model
        if base is not None and model.endswith(".toml") and os.path.isabs(model):
            model = Path(os.path.relpath(model, Path(base).resolve())).as_posix()
        lines = [f'model = "{model}"', ""]
        if note:
            lines = [f"# {line}" for line in note.splitlines()] + [""] + lines
        lines.append("[params]")
        for n, spec in self._specs.items():
            lines.append(f"{n} = {self[n]!r}  # [{spec.unit}] {spec.source}")
        if self.fit_bounds:
            lines += ["", "[bounds]"] + [f"{n} = [{lo!r}, {hi!r}]" for n, lo, hi in self.fit_bounds]
        if self.stderr:
            lines += ["", "[stderr]"] + [f"{n} = {s!r}" for n, s in self.stderr]
        return "\n".join(lines) + "\n"

    def save(self, path: str | os.PathLike, *, overwrite: bool = False, note: str = "") -> Path:
        """Write the set as TOML, atomically; refuses to replace a file unless ``overwrite``."""
        from models.files import atomic_write_text

        return atomic_write_text(path, self.to_toml_string(note, base=Path(path).parent), overwrite=overwrite)


def _rebuild(model, specs, values, fit_bounds, stderr):
    return ParameterSet(model, specs, values, fit_bounds=fit_bounds, stderr=stderr)


#: The six fine-tuned (R [N], omega_G [rad/s], K [N m/rad], c [N m s/rad]) of seed 002 Figs. 9.21-9.26.
LEADSCREW_FINE_TUNED: tuple[tuple[str, float, float, float, float], ...] = (
    ("Fig. 9.21", 152.9, 35.6, 1.18, 1.86e-4),
    ("Fig. 9.22", 273.9, 34.3, 1.31, 3.37e-4),
    ("Fig. 9.23", 314.3, 40.3, 1.65, 3.04e-4),
    ("Fig. 9.24", 327.5, 83.7, 1.75, 4.07e-4),
    ("Fig. 9.25", 330.8, 37.3, 1.88, 5.79e-4),
    ("Fig. 9.26", 336.7, 27.9, 1.67, 4.00e-4),
)
