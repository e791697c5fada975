"""Frozen, typed parameter sets with SI units, bounds and provenance.

Every rig has one parameter-set class.  Each field carries its unit, its physical
bounds and the place in the seeds where its value comes from.  Sets load from and
save to TOML, so that a fitted set can replace the published one in every command::

    model = "rig3"           # which class
    base = "published"       # optional: fill missing fields from the published set

    [params]
    k1 = 1.1175              # N m/rad
    ...

    [bounds]                 # optional: fitting bounds, [lower, upper]
    k1 = [0.5, 2.0]

    [stderr]                 # optional: written by `mitigate identify`
    k1 = 0.004

References
----------
thesis : ``shared/reference/000_*.txt`` (3-disc rig, Tables 3.1-3.5, eqs. 3-1..3-14)
seed 001 : ``shared/reference/001_*.txt`` (2-DOF motor + disc, Table 1)
seed 002 : ``shared/reference/002_*.txt`` (lead-screw drive, Tables 9.3-9.5, Figs. 9.21-9.26)
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from models.errors import ConfigError
from models.checks import read_toml

__all__ = [
    "Spec",
    "ParameterSet",
    "Rig3Params",
    "Rig2Params",
    "LeadScrewParams",
    "DiscParams",
    "PARAM_CLASSES",
    "load_params",
    "published",
    "LEADSCREW_FINE_TUNED",
]


@dataclass(frozen=True)
class Spec:
    """Metadata of one parameter: unit, physical bounds and provenance."""

    unit: str
    lower: float
    upper: float
    source: str
    doc: str = ""
    positive: bool = False  # strict lower bound (> lower) instead of >=


def _p(default: float, unit: str, lower: float, upper: float, source: str, doc: str = "",
       positive: bool = False) -> Any:
    return field(default=default, metadata={"spec": Spec(unit, lower, upper, source, doc, positive)})


@dataclass(frozen=True, kw_only=True)
class ParameterSet:
    """Base class: a frozen set of named, unit-carrying floats.

    Subclasses declare fields with :func:`_p`.  Instances validate themselves: every
    value is finite and within its physical bounds, otherwise :class:`ConfigError`
    names the field, the expectation and the value received.
    """

    model: ClassVar[str] = ""
    fit_bounds: tuple[tuple[str, float, float], ...] = field(default=(), compare=False, repr=False)
    stderr: tuple[tuple[str, float], ...] = field(default=(), compare=False, repr=False)

    # ------------------------------------------------------------------ structure
    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Parameter names in declaration order (the order of :meth:`vector`)."""
        return tuple(f.name for f in dataclasses.fields(cls) if "spec" in f.metadata)

    @classmethod
    def spec(cls, name: str) -> Spec:
        for f in dataclasses.fields(cls):
            if f.name == name and "spec" in f.metadata:
                return f.metadata["spec"]
        raise ConfigError(
            f"{cls.model}: unknown parameter {name!r}; expected one of {', '.join(cls.names())}")

    def __post_init__(self) -> None:
        for name in self.names():
            value = getattr(self, name)
            spec = self.spec(name)
            where = f"params.{self.model}.{name}"
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ConfigError(f"{where} must be a number [{spec.unit}], got {value!r} ({type(value).__name__})")
            value = float(value)
            object.__setattr__(self, name, value)
            if not math.isfinite(value):
                raise ConfigError(f"{where} must be finite [{spec.unit}], got {value}")
            if spec.positive and not value > spec.lower:
                raise ConfigError(f"{where} must be > {spec.lower:g} {spec.unit}, got {value:g}")
            if value < spec.lower or value > spec.upper:
                raise ConfigError(
                    f"{where} must be in [{spec.lower:g}, {spec.upper:g}] {spec.unit}, got {value:g}")
        for name, lo, hi in self.fit_bounds:
            self.spec(name)
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise ConfigError(f"bounds.{name} must be finite, got [{lo}, {hi}]")
            if not lo < hi:
                raise ConfigError(f"bounds.{name} must be [lower, upper] with lower < upper, got [{lo:g}, {hi:g}]")

    # ------------------------------------------------------------------ access
    def as_dict(self) -> dict[str, float]:
        return {n: getattr(self, n) for n in self.names()}

    def vector(self, names: tuple[str, ...] | list[str] | None = None) -> np.ndarray:
        """Values as a float array, in :meth:`names` order unless ``names`` is given."""
        return np.array([getattr(self, n) for n in (names or self.names())], dtype=float)

    def replace(self, **changes: float) -> "ParameterSet":
        """A copy with some values changed (validated)."""
        for n in changes:
            self.spec(n)
        return dataclasses.replace(self, **changes)

    def with_vector(self, names, values) -> "ParameterSet":
        return self.replace(**{n: float(v) for n, v in zip(names, values)})

    def bounds(self, name: str) -> tuple[float, float]:
        """Fitting bounds of a parameter: the user's ``[bounds]`` if given, else physical bounds."""
        for n, lo, hi in self.fit_bounds:
            if n == name:
                return lo, hi
        spec = self.spec(name)
        lo = spec.lower
        if spec.positive:
            lo = spec.lower + max(1e-12, 1e-9 * abs(getattr(self, name)))
        return lo, spec.upper

    def stderr_of(self, name: str) -> float | None:
        for n, s in self.stderr:
            if n == name:
                return s
        return None

    def table(self) -> list[tuple[str, float, str, str]]:
        """(name, value, unit, source) rows for printing."""
        return [(n, getattr(self, n), self.spec(n).unit, self.spec(n).source) for n in self.names()]

    # ------------------------------------------------------------------ TOML
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], where: str = "params") -> "ParameterSet":
        """Build from a TOML-like mapping (see module docstring)."""
        if not isinstance(data, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(data).__name__}")
        allowed = {"model", "base", "params", "bounds", "stderr", "provenance"}
        for key in data:
            if key not in allowed:
                raise ConfigError(f"{where}.{key}: unknown key; expected one of {', '.join(sorted(allowed))}")
        model = data.get("model", cls.model)
        if model != cls.model:
            raise ConfigError(f"{where}.model must be {cls.model!r}, got {model!r}")
        values = data.get("params", {})
        if not isinstance(values, Mapping):
            raise ConfigError(f"{where}.params must be a table, got {type(values).__name__}")
        for key in values:
            if key not in cls.names():
                raise ConfigError(
                    f"{where}.params.{key}: unknown parameter for model {cls.model!r}; "
                    f"expected one of {', '.join(cls.names())}")
        base = data.get("base")
        if base not in (None, "published"):
            raise ConfigError(f"{where}.base must be \"published\" or absent, got {base!r}")
        if base is None:
            missing = [n for n in cls.names() if n not in values]
            if missing:
                raise ConfigError(
                    f"{where}.params: missing field(s) {', '.join(missing)} for model {cls.model!r} "
                    f"(give them, or set base = \"published\")")
        kwargs: dict[str, Any] = dict(values)
        bounds = []
        for key, b in dict(data.get("bounds", {})).items():
            if key not in cls.names():
                raise ConfigError(f"{where}.bounds.{key}: unknown parameter for model {cls.model!r}")
            if not (isinstance(b, list) and len(b) == 2 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in b)):
                raise ConfigError(f"{where}.bounds.{key} must be [lower, upper] numbers, got {b!r}")
            bounds.append((key, float(b[0]), float(b[1])))
        stderr = []
        for key, s in dict(data.get("stderr", {})).items():
            if key not in cls.names():
                raise ConfigError(f"{where}.stderr.{key}: unknown parameter for model {cls.model!r}")
            if not isinstance(s, (int, float)) or isinstance(s, bool) or not math.isfinite(s) or s < 0:
                raise ConfigError(f"{where}.stderr.{key} must be a finite number >= 0, got {s!r}")
            stderr.append((key, float(s)))
        return cls(**kwargs, fit_bounds=tuple(bounds), stderr=tuple(stderr))

    def to_toml_string(self, note: str = "") -> str:
        lines = [f'model = "{self.model}"', ""]
        if note:
            lines = [f"# {line}" for line in note.splitlines()] + [""] + lines
        lines.append("[params]")
        for n in self.names():
            spec = self.spec(n)
            lines.append(f"{n} = {getattr(self, n)!r}  # [{spec.unit}] {spec.source}")
        if self.fit_bounds:
            lines += ["", "[bounds]"] + [f"{n} = [{lo!r}, {hi!r}]" for n, lo, hi in self.fit_bounds]
        if self.stderr:
            lines += ["", "[stderr]"] + [f"{n} = {s!r}" for n, s in self.stderr]
        return "\n".join(lines) + "\n"

    def save(self, path: str | os.PathLike, *, overwrite: bool = False, note: str = "") -> Path:
        """Write the set as TOML, atomically; refuses to replace a file unless ``overwrite``."""
        path = Path(path)
        if path.exists() and not overwrite:
            raise ConfigError(f"{path}: file exists; refusing to overwrite (pass overwrite / --force)")
        tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
        tmp.write_text(self.to_toml_string(note))
        os.replace(tmp, path)
        return path


# --------------------------------------------------------------------------- rigs
_INF = float("inf")


@dataclass(frozen=True, kw_only=True)
class Rig3Params(ParameterSet):
    """The 3-disc drill-string rig of the thesis (R1 far end, R2 middle, R3 motor).

    All mechanical quantities are on the disc side of the 8:1 gearbox except ``Jm``,
    ``Tf`` and ``Cm``, which are on the motor shaft as printed in Table 3.1.
    """

    model: ClassVar[str] = "rig3"
    J1: float = _p(0.02888, "kg m^2", 0.0, 10.0, "thesis Table 3.2 (eq. 3-1)", "disc R1 inertia", True)
    J2: float = _p(0.01496, "kg m^2", 0.0, 10.0, "thesis Table 3.2 (eq. 3-1)", "disc R2 inertia", True)
    Jm: float = _p(0.370e-3, "kg m^2", 0.0, 1.0, "thesis Table 3.1", "motor rotor inertia (motor side); J3 = eta^2 Jm", True)
    eta: float = _p(8.0, "-", 0.0, 1000.0, "thesis Table 3.1", "gearbox ratio (motor turns eta times faster than R3)", True)
    k1: float = _p(1.1175, "N m/rad", 0.0, 1e3, "thesis eq. 3-7", "shaft stiffness R1-R2", True)
    k2: float = _p(0.3659, "N m/rad", 0.0, 1e3, "thesis eq. 3-7", "shaft stiffness R2-R3", True)
    d1: float = _p(0.02145, "N m s/rad", 0.0, 1e2, "thesis eq. 3-9", "shaft damping R1-R2")
    d2: float = _p(0.01595, "N m s/rad", 0.0, 1e2, "thesis eq. 3-9", "shaft damping R2-R3")
    L: float = _p(8.437e-4, "H", 0.0, 1.0, "thesis Table 3.1", "armature inductance", True)
    R: float = _p(0.33, "ohm", 0.0, 1e3, "thesis Table 3.1", "armature resistance", True)
    KT: float = _p(0.126, "N m/A", 0.0, 100.0, "thesis Table 3.1", "torque constant", True)
    KE: float = _p(0.0602, "V s/rad", 0.0, 100.0, "thesis Table 3.1", "back-emf constant")
    Tf: float = _p(0.1196, "N m", 0.0, 100.0, "thesis Table 3.1", "motor Coulomb friction (motor side)")
    Cm: float = _p(1.784e-4, "N m s/rad", 0.0, 10.0, "thesis Table 3.1", "motor viscous friction (motor side)")
    kp: float = _p(2.8, "V s/rad", 0.0, 1e4, "thesis Table 3.1",
                   "PI proportional gain on the disc-side speed error (ASSUMED units, see README)")
    ki: float = _p(3.5, "V/rad", 0.0, 1e4, "thesis Table 3.1",
                   "PI integral gain on the disc-side speed error (ASSUMED units, see README)")
    mu_s: float = _p(0.5, "-", 0.0, 5.0, "thesis eq. 3-11 (Table 3.5)", "static friction coefficient of the pins")
    mu_k: float = _p(0.306, "-", 0.0, 5.0, "thesis eq. 3-14", "kinetic friction coefficient of the pins")
    v_s: float = _p(1.0, "rad/s", 0.0, 1e3, "thesis eq. 3-13 (unit decay speed implied by e^-|w|)",
                    "Stribeck decay speed", True)
    r1: float = _p(0.047, "m", 0.0, 1.0, "thesis eq. 3-10", "pin radius on R1", True)
    r2: float = _p(0.040, "m", 0.0, 1.0, "ASSUMPTION: not printed; same r/R ratio as R1 (0.047/0.095) on D2 = 0.162 m",
                   "pin radius on R2", True)

    @property
    def J3(self) -> float:
        """Motor inertia reflected to the disc side, J3 = eta^2 Jm [kg m^2] (thesis eq. 3-3)."""
        return self.eta ** 2 * self.Jm


@dataclass(frozen=True, kw_only=True)
class Rig2Params(ParameterSet):
    """The 2-DOF motor + disc rig of seed 001, eq. (1), disc side of the gearbox.

    Seed 001 uses regularised Coulomb friction (eq. 4): ``Ts == Tc`` reproduces it; a
    larger ``Ts`` adds a Stribeck drop with decay speed ``v_s`` (composable law).
    """

    model: ClassVar[str] = "rig2"
    Jd: float = _p(0.01496, "kg m^2", 0.0, 10.0, "thesis Table 3.2 (disc D2 of the same rig)", "disc inertia", True)
    Jm: float = _p(0.02368, "kg m^2", 0.0, 10.0, "thesis Table 3.1: eta^2 Jm = 64 x 0.370e-3",
                   "motor inertia, disc side", True)
    k: float = _p(0.3482, "N m/rad", 0.0, 1e3, "seed 001 Table 1 (static test)", "shaft stiffness", True)
    c: float = _p(0.0022, "N m s/rad", 0.0, 1e2, "seed 001 Table 1 (experimental)", "internal (shaft) damping")
    cd: float = _p(0.0, "N m s/rad", 0.0, 1e2, "seed 001 Table 1", "external damping of the disc")
    cm: float = _p(0.0, "N m s/rad", 0.0, 1e2, "seed 001 Table 1", "external damping of the motor")
    Tc: float = _p(0.222, "N m", 0.0, 1e2, "seed 001 Table 1 (PINN; no experimental value printed)",
                   "kinetic Coulomb friction torque T_C = F_C a")
    Ts: float = _p(0.222, "N m", 0.0, 1e2, "seed 001 eq. (4): Ts = Tc (pure Coulomb)", "static friction torque")
    v_s: float = _p(1.0, "rad/s", 0.0, 1e3, "ASSUMPTION (only used when Ts > Tc)", "Stribeck decay speed", True)


@dataclass(frozen=True, kw_only=True)
class LeadScrewParams(ParameterSet):
    """The 1-DOF lead-screw drive of seed 002, eq. (9.31) with friction (9.33)."""

    model: ClassVar[str] = "leadscrew"
    I: float = _p(3.12e-6, "kg m^2", 0.0, 1.0, "seed 002 Table 9.3", "lead screw inertia", True)
    r_m: float = _p(5.183e-3, "m", 0.0, 1.0, "seed 002 Table 9.3 (d_m/2, d_m = 10.366 mm)", "pitch radius", True)
    lam: float = _p(math.radians(5.57), "rad", 0.0, 1.5, "seed 002 Table 9.3 (5.57 deg)", "lead angle")
    m: float = _p(3.8, "kg", 0.0, 1e3, "seed 002 Table 9.3", "mass of translating parts")
    F0: float = _p(0.0, "N", 0.0, 1e3, "seed 002 Table 9.3 (< 2 N, neglected per footnote 8)", "slider resistance")
    T0: float = _p(0.01, "N m", 0.0, 10.0, "seed 002 Sect. 9.5.2", "lead-screw support friction")
    K: float = _p(1.65, "N m/rad", 0.0, 1e3, "seed 002 Fig. 9.23 (R = 314.3 N, wG = 40.3 rad/s)",
                  "overall torsional stiffness", True)
    c: float = _p(3.04e-4, "N m s/rad", 0.0, 1.0, "seed 002 Fig. 9.23", "support damping")
    mu1: float = _p(0.218, "-", -5.0, 5.0, "seed 002 Table 9.5", "Coulomb part")
    mu2: float = _p(2.03e-2, "-", -5.0, 5.0, "seed 002 Table 9.5", "Stribeck part")
    mu3: float = _p(-4.47e-4, "s/rad", -1.0, 1.0, "seed 002 Table 9.5", "viscous part")
    r0: float = _p(0.38, "s/rad", 0.0, 1e3, "seed 002 Table 9.4", "Stribeck decay rate")
    sm: float = _p(1.0, "-", 0.0, 10.0, "seed 002 Fig. 9.30 (close to one)", "friction scaling", True)
    r1: float = _p(20.0, "s/rad", 0.0, 1e6, "ASSUMPTION: 1/r1 = 0.05 rad/s (Fig. 9.28 values not printed)",
                   "zero-speed smoothing rate of (9.33)", True)


#: The six fine-tuned (R [N], omega_G [rad/s], K [N m/rad], c [N m s/rad]) of seed 002 Figs. 9.21-9.26.
LEADSCREW_FINE_TUNED: tuple[tuple[str, float, float, float, float], ...] = (
    ("Fig. 9.21", 152.9, 35.6, 1.18, 1.86e-4),
    ("Fig. 9.22", 273.9, 34.3, 1.31, 3.37e-4),
    ("Fig. 9.23", 314.3, 40.3, 1.65, 3.04e-4),
    ("Fig. 9.24", 327.5, 83.7, 1.75, 4.07e-4),
    ("Fig. 9.25", 330.8, 37.3, 1.88, 5.79e-4),
    ("Fig. 9.26", 336.7, 27.9, 1.67, 4.00e-4),
)


@dataclass(frozen=True, kw_only=True)
class DiscParams(ParameterSet):
    """One disc on a torsional spring whose drive end follows a prescribed speed.

    Defaults are disc R1 of the thesis rig (with R2 as the drive end).
    """

    model: ClassVar[str] = "disc"
    J: float = _p(0.02888, "kg m^2", 0.0, 10.0, "thesis Table 3.2 (R1)", "disc inertia", True)
    k: float = _p(1.1175, "N m/rad", 0.0, 1e3, "thesis eq. 3-7 (k1)", "spring stiffness", True)
    d: float = _p(0.02145, "N m s/rad", 0.0, 1e2, "thesis eq. 3-9 (d1)", "spring damping")
    mu_s: float = _p(0.5, "-", 0.0, 5.0, "thesis eq. 3-11", "static friction coefficient")
    mu_k: float = _p(0.306, "-", 0.0, 5.0, "thesis eq. 3-14", "kinetic friction coefficient")
    v_s: float = _p(1.0, "rad/s", 0.0, 1e3, "thesis eq. 3-13", "Stribeck decay speed", True)
    r: float = _p(0.047, "m", 0.0, 1.0, "thesis eq. 3-10", "pin radius", True)


PARAM_CLASSES: dict[str, type[ParameterSet]] = {
    c.model: c for c in (Rig3Params, Rig2Params, LeadScrewParams, DiscParams)
}


def published(model: str) -> ParameterSet:
    """The published parameter set of a model ("rig3", "rig2", "leadscrew", "disc")."""
    try:
        return PARAM_CLASSES[model]()
    except KeyError:
        raise ConfigError(f"model must be one of {', '.join(PARAM_CLASSES)}, got {model!r}") from None


def load_params(path: str | os.PathLike, model: str | None = None) -> ParameterSet:
    """Load a parameter TOML file; ``model`` (if given) must match the file's ``model`` key."""
    path = Path(path)
    data = read_toml(path, "parameter file")
    name = data.get("model", model)
    if name is None:
        raise ConfigError(f"{path}: missing field 'model' (one of {', '.join(PARAM_CLASSES)})")
    if name not in PARAM_CLASSES:
        raise ConfigError(f"{path}: model must be one of {', '.join(PARAM_CLASSES)}, got {name!r}")
    if model is not None and name != model:
        raise ConfigError(f"{path}: model must be {model!r} here, got {name!r}")
    try:
        return PARAM_CLASSES[name].from_mapping(data, where=str(path))
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
