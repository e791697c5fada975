"""What every drive kind declares and answers (:class:`Drive`), and the registry of kinds.

A drive kind is a subclass of :class:`Drive` that declares what it is -- its set-point's quantity,
whether it acts on a body with a modelled torque or prescribes the speed of the node ``"drive"``,
its parameters in the rig file, its own states -- and implements the physics that only it knows:
the torque it applies, its states' rates, what a torque sensor at it reads, its limits and the power
it draws.  Everything else in the workbench asks the rig's drive (``model.drive``) instead of
testing the kind's name.  Adding a kind is one subclass and one line::

    register(MyDrive)

after which a rig file may say ``[drive] kind = "<MyDrive.kind>"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import casadi as ca
import numpy as np

from models.errors import ConfigError
from models.rig.spec import NODE_DRIVE, SI_UNITS, DriveSpec, Ref

__all__ = ["Drive", "DriveState", "DriveField", "DRIVES", "register", "get_drive", "drive_of"]


@dataclass(frozen=True)
class DriveState:
    """A state a drive adds to the rig's (after the twists and the body speeds).

    Attributes
    ----------
    name : the state's name (``model.states``); unit : its SI unit
    prior : the estimators' family of initial uncertainty for it: ``"current"`` (``p0_current``, an
        armature current [A]) or ``"pi"`` (``p0_pi``, a speed loop's integral [rad])
    noise : the estimators' family of process noise (``"current"``: ``q_current``), or None when the
        state integrates known signals exactly (a PI integral)
    fast : may be taken quasi-statically when it is far faster than the step (an armature current,
        :meth:`Drive.quasi_static`)
    doc : what it is
    """

    name: str
    unit: str
    prior: str
    noise: str | None = None
    fast: bool = False
    doc: str = ""


@dataclass(frozen=True)
class DriveField:
    """A drive parameter of the rig file's ``[drive]`` table: its quantity kind (:data:`SI_UNITS`),
    whether the table must give it, and its physical sign (``strict``: > 0, else >= 0)."""

    name: str
    kind: str
    required: bool = True
    strict: bool = False


class Drive:
    """A rig's drive: the kind's declarations, bound to the rig file's :class:`DriveSpec`.

    Class attributes (the declaration)
    ----------------------------------
    kind : the name a rig file gives (``[drive] kind``)
    doc : one line saying what it is
    setpoint : the quantity of the drive's input, ``"speed"`` [rad/s] or ``"torque"`` [N m]
    on_body : True: the drive acts on its body (``[drive] body``) with a torque the model computes;
        False: it prescribes the speed of the node ``"drive"`` that connections join (a stiff
        speed loop taken as ideal), so the torque it applies is whatever the string needs
    fields : its parameters in ``[drive]`` (:class:`DriveField`)
    keys : other keys ``[drive]`` may hold (read by :meth:`parse_settings`)
    states : the states it adds (:class:`DriveState`)
    definitions : what a torque sensor at the drive may read (``definition = ...``; the first is the
        default), empty when it reads the applied torque
    geared : the drive turns its body through a gearbox (a rotor can be split off with backlash)

    Derived (class attributes a kind may override): :attr:`sets_speed`, :attr:`reverses`,
    :attr:`boundary`, :attr:`unit`, :attr:`rate_unit`.
    """

    kind: ClassVar[str] = ""
    doc: ClassVar[str] = ""
    setpoint: ClassVar[str] = "speed"
    on_body: ClassVar[bool] = True
    fields: ClassVar[tuple[DriveField, ...]] = ()
    keys: ClassVar[frozenset[str]] = frozenset()
    states: ClassVar[tuple[DriveState, ...]] = ()
    definitions: ClassVar[tuple[str, ...]] = ()
    geared: ClassVar[bool] = False

    #: whether the input is a speed (a set-point the drive follows, or the speed it prescribes): the
    #: programme then sets the rig's sliding speed; a torque input leaves the speed to the balance of
    #: torques (the operating point solves it).  Follows from :attr:`setpoint`.
    sets_speed: ClassVar[bool] = True
    #: whether a controller may move the set-point through zero: a speed set-point does not reverse
    #: the rotation; a torque does (it brakes).  Default: not :attr:`sets_speed`.
    reverses: ClassVar[bool] = False
    #: the condition the drive puts on the top of the string for its torsional modes and its
    #: stick-slip period: ``"clamped"`` when it holds a speed (its speed loop far stiffer than the
    #: string), ``"free"`` when it applies a torque (the drive body moves with the string, with its
    #: own inertia).  Default: from :attr:`sets_speed`.
    boundary: ClassVar[str] = "clamped"
    #: the SI unit of the set-point, and of its rate
    unit: ClassVar[str] = "rad/s"
    rate_unit: ClassVar[str] = "rad/s^2"

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        own = vars(cls)
        cls.sets_speed = cls.setpoint == "speed"
        if "reverses" not in own:
            cls.reverses = not cls.sets_speed
        if "boundary" not in own:
            cls.boundary = "clamped" if cls.sets_speed else "free"
        cls.unit = SI_UNITS.get(cls.setpoint, "")
        cls.rate_unit = {"speed": "rad/s^2", "torque": "N m/s"}.get(cls.setpoint, "")

    def __init__(self, spec: DriveSpec):
        self.spec = spec

    def __repr__(self) -> str:
        body = f", body {self.body!r}" if self.on_body else ""
        return f"{type(self).__name__}({self.kind!r}, input {self.input!r}{body})"

    # ------------------------------------------------------------------ the declaration's answers
    @property
    def input(self) -> str:
        """The drive's input (a speed set-point, a prescribed speed or a torque)."""
        return self.spec.input

    @property
    def body(self) -> str:
        """The body the drive acts on ("" when it prescribes the node ``"drive"``)."""
        return self.spec.body

    @property
    def node(self) -> str:
        """The node whose speed is the drive's: its body, or ``"drive"``."""
        return self.spec.body if self.on_body else NODE_DRIVE

    def param(self, name: str) -> Ref | None:
        """The reference of drive parameter ``name``, or None."""
        return self.spec.param(name)

    # ------------------------------------------------------------------ rig file
    @classmethod
    def allowed_keys(cls) -> set[str]:
        """The keys its ``[drive]`` table may hold."""
        body = {"body"} if cls.on_body else set()
        return {"kind", "input", "doc"} | body | {f.name for f in cls.fields} | set(cls.keys)

    @classmethod
    def parse_settings(cls, table: Mapping[str, Any], ctx) -> dict:
        """The :class:`DriveSpec` settings other than the kind, input, body and parameters that the
        kind reads from its ``[drive]`` table (``ctx``: :class:`models.rig.fields.Context`)."""
        return {}

    @classmethod
    def reflected_inertia(cls, value: Callable[[Ref | None], Any], spec: DriveSpec):
        """The inertia a :attr:`geared` drive adds to its body [kg m^2] (its rotor through the gearbox),
        given ``value(ref)`` of its parameters (symbolic or numeric; None while unknown, then None)."""
        return 0.0

    # ------------------------------------------------------------------ dynamics
    def torque(self, model, x, un, P):
        """The torque the drive applies to its body [N m] (``un``: inputs by name; ``P``: parameters)."""
        raise NotImplementedError(f"drive kind {self.kind!r} applies no torque to a body")

    def rates(self, model, x, un, P) -> list:
        """The time derivatives of :attr:`states` (in that order)."""
        return []

    def state_index(self, model, name: str) -> int:
        """Index of the drive state ``name`` in ``model.states``."""
        return model.nx - len(self.states) + [s.name for s in self.states].index(name)

    @property
    def fast_state(self) -> str | None:
        """The state that may be taken quasi-statically (:attr:`DriveState.fast`), or None."""
        return next((s.name for s in self.states if s.fast), None)

    def quasi_static(self, model, x, un, P):
        """The :attr:`fast_state`'s value with its own dynamics neglected (e.g. an armature current
        with the inductance neglected)."""
        raise NotImplementedError(f"drive kind {self.kind!r} has no fast state")

    def electrical_time_constant(self, P) -> float:
        """The time constant of the :attr:`fast_state` [s] (0 without one); ``P`` numeric by name."""
        return 0.0

    def limit_refs(self) -> tuple[Ref, ...]:
        """The parameters of limits that are flat outside their range (a supply voltage, a current
        limit): the steady-sliding solve starts without them."""
        return ()

    def project(self, model, x, u, P):
        """``x`` (a rig state, possibly augmented after ``model.nx``) with the drive's states moved to
        what the drive can reach (an estimator's corrected mean; symbolic)."""
        return x

    # ------------------------------------------------------------------ readings
    def outputs(self, model, x, un, P) -> dict:
        """Physical quantities of the drive beyond the sensors (``{name: value}``) and their units
        (:meth:`output_units`)."""
        return {}

    def output_units(self) -> dict[str, str]:
        return {}

    @classmethod
    def torque_sensor(cls, sensor: Mapping[str, Any], field_: str, ctx) -> dict:
        """The :class:`SensorSpec` settings of a torque sensor at the drive (``at = "drive"``): its
        ``definition`` if the kind has :attr:`definitions`."""
        if not cls.on_body:
            raise ctx.err(f"{field_}.at", f"a {cls.kind} drive has no torque to measure; put the sensor on a "
                                          "connection")
        if cls.definitions:
            d = sensor.get("definition", cls.definitions[0])
            if d not in cls.definitions:
                raise ctx.err(f"{field_}.definition", f"must be {' or '.join(map(repr, cls.definitions))}, got {d!r}")
            return {"definition": d}
        if "definition" in sensor:
            raise ctx.err(f"{field_}.definition", f"applies only to a DC motor's torque (a {cls.kind} drive's sensor "
                                                 "reads the applied torque)")
        return {}

    def torque_reading(self, model, sensor, x, u, un, P):
        """What a torque sensor at the drive reads (before its gain and offset) [N m]."""
        return self.torque(model, x, un, P)

    def pipe_torque_terms(self, model, sensor, P) -> tuple[float, Callable[[float], float] | None]:
        """``(J, loss)``: a torque sensor at the drive reads ``T_pipe + J w' + loss(w)`` (``w`` the
        drive body's speed [rad/s], ``loss`` None for none): what a controller subtracts to find
        the torque the string loads the drive with."""
        return float(model.inertia(self.body, P)), None

    def pipe_torque_loss(self, model, sensor, P):
        """The loss in :meth:`pipe_torque_terms` as numbers ``(ratio, Tf, Cm, eps)`` of a geared
        motor's friction ``ratio (Tf tanh(ratio w / eps) + Cm ratio w)`` (what the compiled laws
        evaluate), or None for no loss."""
        return None

    def torque_on_body(self, model, sensor, T, w, acc, P):
        """``(T_in, delivered)`` from a torque sensor's reading ``T`` (arrays over a log, gain and
        offset removed; ``w``, ``acc`` the drive body's speed and acceleration or None): the torque
        the drive puts into its body's equation of motion, and the torque its shaft delivers when the
        reading gives it (else None).  ``(None, None)`` when it cannot be told."""
        return T, None

    # ------------------------------------------------------------------ along a run: signals, limits and energy
    def signals(self, model, params, X, U) -> dict[str, np.ndarray]:
        """The drive's electrical and torque quantities along a trajectory, what a bench's drive reports
        beside the sensors: ``{name: (n,) array}`` in the units of :meth:`signal_units`.

        The default is the torque the drive applies to its body, ``drive_torque`` [N m] (a torque
        drive's applied input; none for a prescribed speed, whose torque the model does not know).

        Parameters
        ----------
        model : the rig the trajectory belongs to; params : its parameter set
        X : (n, nx) states; U : (n, nu) applied inputs (order ``model.inputs``)
        """
        if not self.on_body:
            return {}
        x, u = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu)
        un = {name: u[j] for j, name in enumerate(model.inputs)}
        f = ca.Function("drive_torque", [x, u], [self.torque(model, x, un, params.as_dict())])
        return {"drive_torque": _mapped(f, X, U)}

    def signal_units(self) -> dict[str, str]:
        """The SI unit of every name :meth:`signals` gives."""
        return {"drive_torque": "N m"} if self.on_body else {}

    def limit(self, P) -> tuple[str, float] | None:
        """``(signal, limit)``: which of :meth:`signals` the rig limits and its limit in that signal's
        unit (default: ``drive_torque`` and :meth:`torque_limit`), or None when the rig declares no
        limit (``P``: parameter values by name)."""
        lim = self.torque_limit(P)
        return ("drive_torque", lim) if self.on_body and math.isfinite(lim) else None

    def peak_ratio(self, model, params, X, U) -> float:
        """The peak of the limited signal's magnitude along a trajectory over its limit [-]
        (:meth:`limit`; above 1: the run exceeded the drive's limit), NaN when the rig declares none."""
        lim = self.limit(params.as_dict())
        if lim is None or not len(X):
            return math.nan
        s = np.abs(self.signals(model, params, X, U)[lim[0]])
        return float(np.max(s[np.isfinite(s)], initial=0.0)) / lim[1]

    def torque_limit(self, P=None) -> float:
        """The largest torque the drive can apply [N m] (inf: none)."""
        return math.inf

    def current_limit(self, P) -> float:
        """The drive's current limit [A] (nan: none)."""
        return math.nan

    def power(self, model, params, X, U):
        """The power the drive draws along a trajectory [W] ((n,) array, ``X`` (n, nx), ``U`` (n, nu)),
        or None when the model does not know it (a prescribed speed)."""
        return None


def _mapped(f, X, U) -> np.ndarray:
    """``f(x, u)`` (a scalar CasADi Function) over the rows of ``X`` (n, nx) and ``U`` (n, nu): (n,)."""
    X, U = np.asarray(X, float), np.asarray(U, float)
    if not X.shape[0]:
        return np.zeros(0)
    return np.asarray(f.map(X.shape[0])(X.T, U.T), float).ravel()


#: the registered drive kinds by name
DRIVES: dict[str, type[Drive]] = {}


def register(kind: type[Drive]) -> type[Drive]:
    """Add the drive kind ``kind`` (a :class:`Drive` subclass with a new ``kind`` name)."""
    if not (isinstance(kind, type) and issubclass(kind, Drive)):
        raise TypeError(f"register expects a Drive subclass, got {kind!r}")
    if not kind.kind or kind.kind in DRIVES:
        raise ConfigError(f"drive kind {kind.kind!r} is {'already registered' if kind.kind else 'unnamed'}")
    if kind.setpoint not in ("speed", "torque"):
        raise ConfigError(f"drive kind {kind.kind!r}: setpoint must be 'speed' or 'torque', got {kind.setpoint!r}")
    if kind.boundary not in ("clamped", "free"):
        raise ConfigError(f"drive kind {kind.kind!r}: boundary must be 'clamped' or 'free', got {kind.boundary!r}")
    DRIVES[kind.kind] = kind
    return kind


def get_drive(name: Any, where: str = "drive.kind") -> type[Drive]:
    """The registered drive kind ``name``; a one-line ConfigError lists the known ones."""
    try:
        return DRIVES[name]
    except (KeyError, TypeError):
        raise ConfigError(f"{where} must be one of {', '.join(sorted(DRIVES))}, got {name!r}") from None


def drive_of(spec: DriveSpec) -> Drive:
    """The drive of a rig file's :class:`DriveSpec`."""
    return get_drive(spec.kind)(spec)
