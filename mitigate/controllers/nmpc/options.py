"""Options of the NMPC: what it may set (``inputs``), whose stick-slip it suppresses (``body``),
its cost weights, limits and solver.

Both dataclasses are frozen and keyword-only and validate themselves; everything that needs
the rig (does it have that input, that body?) is checked when the controller is built
(:class:`mitigate.controllers.nmpc.controller.NMPC`), with the same one-line errors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Mapping

from models.checks import finite_number
from models.errors import ConfigError
from mitigate.controllers.nmpc.qp import QP_SOLVERS

__all__ = ["NMPCOptions", "NMPCWeights", "MAX_HORIZON", "MAX_SUBSTEPS", "INPUT_MODES", "SOLVERS", "WEIGHT_NAMES"]

#: OCP solvers (:func:`mitigate.controllers.nmpc.solvers.make_ocp_solver`)
SOLVERS = ("rti", "sqp", "ipopt")
#: implementations of the step: the compiled C core, the Python reference
IMPLEMENTATIONS = ("c", "python")
#: ``inputs`` keywords: every command the rig offers, its servo inputs only, its drive only
INPUT_MODES = ("both", "pin", "motor")
# The OCP, its build and each QP grow with the horizon.  N = 500 plans 25 s ahead at dt = 0.05 s
# (a stick-slip cycle is about 2 s) and builds in about 3 s (N = 20: 0.2 s; without compile);
# N = 100000 would take about 9 minutes to build before the first sample.
MAX_HORIZON = 500
#: RK4 substeps per interval beyond which the stage function is too big to build and to evaluate in
#: real time (rig3 at dt = 0.05 s and eps = 0.05 rad/s needs 22; the lead screw at 0.05 s would need 38013)
MAX_SUBSTEPS = 200
#: the cost weights, in the order the OCP's parameter vector holds them
WEIGHT_NAMES = ("speed", "rel", "ref", "force", "force_linear", "d_ref", "d_force", "terminal")


@dataclass(frozen=True, kw_only=True)
class NMPCWeights:
    """Dimensionless weights of the NMPC cost.  Speeds are scaled by the nominal speed, forces by
    the servo's ``n_max``, a torque set-point by ``setpoint_band``.

    speed : objective body's speed - nominal speed (its stick-slip, and the mean speed)
    rel : relative speed across every spring connection (the torsional modes)
    ref : drive set-point - the programme's (stay near the programme)
    force : quadratic servo force; force_linear : linear servo force (friction work and wear at
        the pin; a linear cost leaves the force at exactly 0 when it does not pay)
    d_ref : set-point change per OCP interval; d_force : servo activity, (command - servo force)
        = tau x the servo's rate
    terminal : factor on the terminal speed residuals

    The same defaults serve the motor-only NMPC (``inputs = "motor"``): on the 30 rpm stick-slip
    case they were within a few percent of the best of 13 weight sets with the true state, with
    0.3 rad/s of noise on it and with a 20 % model mismatch; lowering ``ref`` or ``d_ref`` settled
    no faster and passed more noise to the set-point, raising ``d_ref`` to 1 halved the noise but
    doubled the settling time (benchmarks/results/nmpc.md).
    """

    speed: float = 1.0
    rel: float = 0.3
    ref: float = 0.2
    force: float = 0.2
    force_linear: float = 0.01
    d_ref: float = 0.3
    d_force: float = 0.3
    terminal: float = 3.0
    where: str = "nmpc.weights"

    def __post_init__(self):
        for name in WEIGHT_NAMES:
            v = finite_number(getattr(self, name), f"{self.where}.{name}", nonneg=True)
            if name in ("d_ref", "d_force") and not v > 0:
                raise ConfigError(f"{self.where}.{name} must be > 0 (it keeps the QP positive definite), got {v!r}")
            object.__setattr__(self, name, v)

    def as_tuple(self) -> tuple[float, ...]:
        """The weights in :data:`WEIGHT_NAMES` order."""
        return tuple(getattr(self, k) for k in WEIGHT_NAMES)

    @classmethod
    def from_mapping(cls, table: Mapping, where: str) -> "NMPCWeights":
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(table).__name__}")
        bad = sorted(set(table) - set(WEIGHT_NAMES))
        if bad:
            raise ConfigError(f"{where}: unknown weight(s) {bad}; expected some of {list(WEIGHT_NAMES)}")
        return cls(**dict(table), where=where)


def _int(v, where: str, lo: int, hi: int | None = None, what: str = "") -> None:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ConfigError(f"{where} must be an integer >= {lo}{what}, got {v!r}")
    if hi is not None and v > hi:
        raise ConfigError(f"{where} must be <= {hi} (OCP intervals; the OCP and each QP grow with it), got {v}")


@dataclass(frozen=True, kw_only=True)
class NMPCOptions:
    """NMPC options (a scenario's ``[[controllers]]`` keys with ``kind = "nmpc"``).

    Parameters
    ----------
    horizon : OCP intervals N (2 .. :data:`MAX_HORIZON`)
    dt : OCP interval [s] (>= the DAQ period); the NMPC re-plans every ``dt`` (None: a 40th of
        the rig's stick-slip period, :mod:`mitigate.controllers.nmpc.defaults`)
    substeps : RK4 substeps per interval (0: the fewest that keep RK4 stable, ``|h lambda| <= 2.5``;
        at most :data:`MAX_SUBSTEPS`)
    eps : friction regularisation of the prediction model [rad/s] (None: 1.6 % of the nominal speed)
    inputs : what the NMPC sets: "both" (the drive's set-point and every servo input), "pin"
        (the servo inputs only; the set-point follows the programme), "motor" (the drive's
        set-point only; no servo force), or a list of input names from the rig's ``commands``.
        Inputs it does not set are held over the horizon at their measured value (a normal
        force from its load cell) or, for the drive, at the programme's
    body : the body whose stick-slip the cost suppresses (None: the rig's ``objective_body``)
    speed : nominal speed of that body [rad/s] (None: the programme's drive speed; a torque
        drive: the scenario's ``[control] speed``, else the rig's ``operating_point.speed``)
    weights : :class:`NMPCWeights` (or a table of them)
    setpoint_band : the drive's set-point stays within the programme's +- this [rad/s, or N m
        for a torque drive] (a speed set-point never changes sign; None: the programme's own
        set-point, so a speed set-point stays in [0, 2 w_prog])
    setpoint_rate : rate limit of the set-point [rad/s^2, or N m/s] (None: 15 bands per
        stick-slip period)
    solver : "rti" (one Gauss-Newton QP per plan), "sqp" (Gauss-Newton to convergence), "ipopt"
        (exact Hessian; the reference)
    compile : compile the stage function with gcc (cached on disk) for rti/sqp
    qp_solver : "hpipm" (called directly), "qrqp" or "osqp" (CasADi ``conic``)
    qp_tol : QP tolerance.  hpipm ("speed_abs" mode) at 1e-7 moves the first input by < 3e-3
        rad/s and < 0.04 N against an exact active-set solve (tests/test_nmpc.py), in about 4
        interior-point iterations; "sqp" uses min(qp_tol, sqp_tol / 10)
    sqp_max_iter : Gauss-Newton iterations of "sqp"
    model_servo : predict each servo's first-order lag (tau of the rig's actuator); without it
        the servo force is the previous command and the rate limit acts per interval
    prepare_ahead : RTI preparation/feedback split: linearise at the shifted plan in the first
        call after a plan (a held sample), so a planning call only embeds the state and solves the QP
    use_load_estimate : scale a contact's friction in the prediction by the estimate's
        ``load:<contact>`` state when it has one (the EKF's disturbance model)
    force_filter : time constant [s] of the low-pass on (load-cell reading - programme) of a
        held normal force (None: the horizon, ``horizon dt``; 0: the raw reading)
    hold_gain : factor on the ``ref`` and ``d_ref`` weights (its square on ``force`` when the drive is
        commanded too) once the objective body slides calmly
        (:mod:`mitigate.controllers.nmpc.schedule`; 1: the same weights always).  None: from the
        rig (:mod:`mitigate.controllers.nmpc.defaults`): 60 where steady sliding at the programme
        is linearly stable (calm, the plan only has to stay out of the way), 15 where it is not
        (calm, the plan must keep damping an unstable equilibrium)
    calm_band : ``(s_lo, s_hi)``: the estimated severity over one stick-slip period below which
        the NMPC holds (``hold_gain``) and above which it suppresses (factor 1); log-linear between
    speed_trim : time constant [s] of the offset-free trim of the speed target by the objective
        body's mean speed (:mod:`mitigate.controllers.nmpc.supervision`); None: one stick-slip period;
        0: no trim
    implementation : "c": the step as one compiled C call (csrc/ss_nmpc.c; the one that
        ``mitigate export`` writes out; solver "rti" or "sqp" with hpipm, ``compile = true``);
        "python": the reference implementation of the same step in Python (the IPOPT and CasADi
        QP solvers, and ``compile = false``, always run it)
    """

    horizon: int = 20
    dt: float | None = None
    substeps: int = 0
    eps: float | None = None
    inputs: str | tuple[str, ...] = "both"
    body: str | None = None
    speed: float | None = None
    weights: NMPCWeights = NMPCWeights()
    setpoint_band: float | None = None
    setpoint_rate: float | None = None
    solver: str = "rti"
    compile: bool = True
    qp_solver: str = "hpipm"
    qp_tol: float = 1e-7
    sqp_max_iter: int = 20
    model_servo: bool = True
    prepare_ahead: bool = True
    use_load_estimate: bool = True
    force_filter: float | None = None
    hold_gain: float | None = None
    calm_band: tuple[float, float] = (0.01, 0.1)
    speed_trim: float | None = None
    implementation: str = "c"
    where: str = "nmpc"

    def __post_init__(self):
        w = self.where
        _int(self.horizon, f"{w}.horizon", 2, MAX_HORIZON)
        if self.dt is not None:
            finite_number(self.dt, f"{w}.dt", positive=True, unit="s")
        _int(self.substeps, f"{w}.substeps", 0, what=" (0 = automatic)")
        if self.substeps > MAX_SUBSTEPS:
            raise ConfigError(f"{w}.substeps must be <= {MAX_SUBSTEPS}, got {self.substeps}")
        if self.eps is not None:
            finite_number(self.eps, f"{w}.eps", positive=True, unit="rad/s")
        inp = self.inputs
        if isinstance(inp, str):
            if inp not in INPUT_MODES:
                raise ConfigError(f"{w}.inputs must be one of {', '.join(INPUT_MODES)} or a list of input names, "
                                  f"got {inp!r}")
        elif isinstance(inp, (list, tuple)):
            if not inp or not all(isinstance(n, str) and n for n in inp) or len(set(inp)) != len(inp):
                raise ConfigError(f"{w}.inputs must be a non-empty list of distinct input names, got {list(inp)!r}")
            object.__setattr__(self, "inputs", tuple(inp))
        else:
            raise ConfigError(f"{w}.inputs must be one of {', '.join(INPUT_MODES)} or a list of input names, "
                              f"got {inp!r}")
        if self.body is not None and (not isinstance(self.body, str) or not self.body):
            raise ConfigError(f"{w}.body must be a body name, got {self.body!r}")
        if self.speed is not None:
            finite_number(self.speed, f"{w}.speed", unit="rad/s")
        if isinstance(self.weights, Mapping):
            object.__setattr__(self, "weights", NMPCWeights.from_mapping(self.weights, f"{w}.weights"))
        if not isinstance(self.weights, NMPCWeights):
            raise ConfigError(f"{w}.weights must be a table of weights, got {type(self.weights).__name__}")
        if self.setpoint_band is not None:
            finite_number(self.setpoint_band, f"{w}.setpoint_band", nonneg=True)
        if self.setpoint_rate is not None:
            finite_number(self.setpoint_rate, f"{w}.setpoint_rate", positive=True)
        if self.solver not in SOLVERS:
            raise ConfigError(f"{w}.solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if self.qp_solver not in QP_SOLVERS:
            raise ConfigError(f"{w}.qp_solver must be one of {', '.join(QP_SOLVERS)}, got {self.qp_solver!r}")
        finite_number(self.qp_tol, f"{w}.qp_tol", positive=True)
        _int(self.sqp_max_iter, f"{w}.sqp_max_iter", 1)
        if self.hold_gain is not None:
            finite_number(self.hold_gain, f"{w}.hold_gain", positive=True)
        band = self.calm_band
        if not (isinstance(band, (list, tuple)) and len(band) == 2
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in band)
                and 0 < band[0] < band[1]):
            raise ConfigError(f"{w}.calm_band must be two severities 0 < s_lo < s_hi, got {band!r}")
        object.__setattr__(self, "calm_band", (float(band[0]), float(band[1])))
        if self.force_filter is not None:
            finite_number(self.force_filter, f"{w}.force_filter", nonneg=True, unit="s")
        if self.speed_trim is not None:
            finite_number(self.speed_trim, f"{w}.speed_trim", nonneg=True, unit="s")
        if self.implementation not in IMPLEMENTATIONS:
            raise ConfigError(f"{w}.implementation must be one of {', '.join(IMPLEMENTATIONS)}, got {self.implementation!r}")
        for name in ("compile", "model_servo", "prepare_ahead", "use_load_estimate"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{w}.{name} must be true or false, got {getattr(self, name)!r}")

    @classmethod
    def from_mapping(cls, options: Mapping, where: str = "nmpc") -> "NMPCOptions":
        """Validate a raw scenario table (unknown keys are errors naming ``where``)."""
        if not isinstance(options, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(options).__name__}")
        known = [f.name for f in fields(cls) if f.name != "where"]
        opts = dict(options)
        unknown = sorted(set(opts) - set(known))
        if unknown:
            raise ConfigError(f"{where}: unknown NMPC option(s) {unknown}; expected some of {known}")
        if "weights" in opts:
            opts["weights"] = NMPCWeights.from_mapping(opts["weights"], f"{where}.weights")
        return cls(**opts, where=where)
