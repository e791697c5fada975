"""Options of the NMPC: what it may set (``inputs``), whose stick-slip it suppresses (``body``),
its cost weights, limits and solver.

Both dataclasses are frozen and keyword-only and declare their checks with
:func:`models.checks.option` (a raw scenario table becomes them through
:func:`models.checks.options_from_mapping`); everything that needs
the rig (does it have that input, that body?) is checked when the controller is built
(:class:`mitigate.controllers.nmpc.controller.NMPC`), with the same one-line errors.
"""

from __future__ import annotations

from dataclasses import dataclass

from models.checks import check_options, option, options_from_mapping, where_field
from models.errors import ConfigError
from mitigate.controllers.nmpc.qp import HPIPM_MODES, QP_SOLVERS
from mitigate.metrics.quantities import straddles_one

__all__ = ["NMPCOptions", "NMPCWeights", "MAX_HORIZON", "MAX_SUBSTEPS", "INPUT_MODES", "SOLVERS", "WEIGHT_NAMES", "QP_CONDENSING",
           "HPIPM_MODES", "qp_blocks"]

#: QP condensing of the compiled step (``qp_condensing``; its index is the C core's ``qp_cond``)
QP_CONDENSING = ("none", "full", "partial")
#: stages per block of the partially condensed QP where ``qp_blocks`` is not given (:func:`qp_blocks`)
QP_BLOCK_STAGES = 5


def qp_blocks(blocks: int | None, horizon: int) -> int:
    """Stages of the partially condensed QP: ``blocks``, else ``ceil(horizon / QP_BLOCK_STAGES)``;
    never more than the horizon."""
    n = -(-horizon // QP_BLOCK_STAGES) if blocks is None else int(blocks)
    return max(1, min(n, horizon))
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

    speed: float = option(1.0, lo=0.0)
    rel: float = option(0.3, lo=0.0)
    ref: float = option(0.2, lo=0.0)
    force: float = option(0.2, lo=0.0)
    force_linear: float = option(0.01, lo=0.0)
    d_ref: float = option(0.3, lo=0.0, lo_open=True, why="it keeps the QP positive definite")
    d_force: float = option(0.3, lo=0.0, lo_open=True, why="it keeps the QP positive definite")
    terminal: float = option(3.0, lo=0.0)
    where: str = where_field("nmpc.weights")

    def __post_init__(self):
        check_options(self)

    def as_tuple(self) -> tuple[float, ...]:
        """The weights in :data:`WEIGHT_NAMES` order."""
        return tuple(getattr(self, k) for k in WEIGHT_NAMES)


def _at_most(limit: int, why: str = ""):
    """A :func:`models.checks.option` hook: an upper limit that is a cost, not a meaning (its own message)."""
    def check(v, where):
        if v > limit:
            raise ConfigError(f"{where} must be <= {limit}{f' ({why})' if why else ''}, got {v}")
    return check


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
    force_band : ``(low, high)``: a commanded servo force whose programme is positive (a weight on
        bit) stays within ``[low, high]`` times the programme at every sample (or, with a
        ``force_window``, on its mean over every such window), inside the servo's range: the
        driller's band that the metrics judge (None:
        :data:`mitigate.metrics.quantities.FORCE_BAND`, the default of ``MetricOptions.force_band``;
        ``[0, inf]``: the servo's whole range).  A zero programme (a brake) has no band
    force_window : 0: every command within ``force_band`` (no window the metrics may judge can
        leave it); > 0: the moving window [s] whose mean applied force the band keeps, counting
        the servo's lag and rate limit (:mod:`mitigate.controllers.nmpc.band`).  Safe only where
        the judged window is known and this long (docs/nmpc.md: it lost job-done runs where the
        benchmark's window, the measured period, differed from the rig's estimate)
    solver : "rti" (one Gauss-Newton QP per plan), "sqp" (Gauss-Newton to convergence), "ipopt"
        (exact Hessian; the reference)
    compile : compile the stage function with gcc (cached on disk) for rti/sqp
    qp_solver : "hpipm" (called directly), "qrqp" or "osqp" (CasADi ``conic``)
    qp_tol : QP tolerance.  hpipm ("speed_abs" mode) at 1e-7 moves the first input by < 3e-3
        rad/s and < 0.04 N against an exact active-set solve (tests/test_nmpc.py), in about 4
        interior-point iterations; "sqp" uses min(qp_tol, sqp_tol / 10)
    qp_condensing : "none": hpipm's Riccati interior point on the OCP QP; "full": the QP condensed onto
        the inputs (and x0), its matrices in the RTI preparation, hpipm's dense interior point in the
        feedback (as acados' full condensing); "partial": condensed in blocks to ``qp_blocks`` stages
        (hpipm's partial condensing), Riccati on that.  The compiled C step only
        (``implementation = "c"``); not the default: its plans equal the structured solve's only to
        the QP's tolerance
    qp_blocks : stages of the partially condensed QP (None: ``ceil(horizon / 5)``; more than the
        horizon counts as the horizon: no condensing)
    qp_mode : hpipm's preset: "speed_abs" (stops when the complementarity is below ``qp_tol``,
        residuals never computed), "speed", "balance" or "robust" (each stops when every residual is
        below ``qp_tol``).  hpipm only
    qp_mu0 : hpipm's initial complementarity (None: the preset's, 10).  On the main scenario's
        closed loop (rig3, N = 20 and 50, 8 s out of stick-slip) "speed" with ``qp_mu0 = 0.01``
        took 4 interior-point iterations (median) where the default took 9, and its first moves
        were within 4e-5 N and 6e-6 rad/s of a QP solved to 1e-10 at the 95th percentile, where the
        default's ("speed_abs", which checks no residual) were within 3e-3 N and 1.2e-3 rad/s
        (docs/nmpc.md).  hpipm only
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

    horizon: int = option(20, lo=2, check=_at_most(MAX_HORIZON, "OCP intervals; the OCP and each QP grow with it"))
    dt: float | None = option(None, lo=0.0, lo_open=True, unit="s", none=True)
    substeps: int = option(0, lo=0, why="0 = automatic", check=_at_most(MAX_SUBSTEPS))
    eps: float | None = option(None, lo=0.0, lo_open=True, unit="rad/s", none=True)
    inputs: str | tuple[str, ...] = option("both", kind="names", words=INPUT_MODES, what="input names", nonempty=True,
                                           unique=True)
    body: str | None = option(None, what="a body name", nonempty=True, kind="text", none=True)
    speed: float | None = option(None, unit="rad/s", none=True)
    weights: NMPCWeights = option(NMPCWeights(), table=NMPCWeights, what="a table of weights")
    setpoint_band: float | None = option(None, lo=0.0, none=True)
    setpoint_rate: float | None = option(None, lo=0.0, lo_open=True, none=True)
    force_band: tuple[float, float] | None = option(None, items=2, lo=0.0, finite=False, none=True, check=straddles_one,
                                                    what="[low, high] (ratios to the programme)")
    force_window: float = option(0.0, lo=0.0, unit="s")
    solver: str = option("rti", choices=SOLVERS)
    compile: bool = option(True)
    qp_solver: str = option("hpipm", choices=QP_SOLVERS)
    qp_tol: float = option(1e-7, lo=0.0, lo_open=True)
    qp_condensing: str = option("none", choices=QP_CONDENSING)
    qp_blocks: int | None = option(None, lo=1, none=True)
    qp_mode: str = option("speed_abs", choices=tuple(HPIPM_MODES))
    qp_mu0: float | None = option(None, lo=0.0, lo_open=True, none=True)
    sqp_max_iter: int = option(20, lo=1)
    model_servo: bool = option(True)
    prepare_ahead: bool = option(True)
    use_load_estimate: bool = option(True)
    force_filter: float | None = option(None, lo=0.0, unit="s", none=True)
    hold_gain: float | None = option(None, lo=0.0, lo_open=True, none=True)
    calm_band: tuple[float, float] = option((0.01, 0.1), items=2, lo=0.0, lo_open=True, increasing=True,
                                            what="two severities 0 < s_lo < s_hi")
    speed_trim: float | None = option(None, lo=0.0, unit="s", none=True)
    implementation: str = option("c", choices=IMPLEMENTATIONS)
    where: str = where_field("nmpc")

    def __post_init__(self):
        check_options(self)

    #: the controller's call site reads a raw table with this name; it is :func:`models.checks.options_from_mapping`
    from_mapping = classmethod(options_from_mapping)
