"""How a rig is integrated over one step: the ONE rule every consumer follows.

The plant, the EKF and the MHE, the NMPC and identification all advance a rig over a fixed
step ``dt`` (a DAQ sample, an NMPC interval) with the input held.  :func:`integration` decides
how, from the rig's own rates, and :meth:`Integration.advance` does it:

- **RK4 with substeps**, ``h |lambda|max <= RHO`` (:data:`RHO` = 2.5, inside RK4's stability
  region, 2.78 on the real axis and 2.83 on the imaginary one), ``lambda`` the eigenvalues of
  the model's Jacobian at steady sliding under the consumer's largest inputs with every contact
  body at rest or sliding (all combinations, up to 4 contact bodies), and any extra rates the
  consumer adds (servo lags).  The regularised friction is what makes the model stiff near zero
  speed (``N r mu / (eps J)``, ``shared/CASADI-FACTS.md``); the exact stick/slip plant has no
  such rate (a stuck body is held), so for it (``eps=None``) only the sliding point counts.
- **The armature current treated quasi-statically** when a DC motor's electrical time
  constant ``L/R`` is far below the substep the rest of the rig needs (at most
  1/:data:`QS_FACTOR` of it).  The current then follows ``L i' = V - R i - KE w_m`` with
  ``L -> 0``: ``i = (V - KE w_m)/R`` (:meth:`models.rig.RigModel.quasi_static_current`),
  substituted at every RK4 stage and at the end of the step, so the state keeps its layout
  (the current is still a state, consistent with the others).  The neglected dynamics decay
  as ``exp(-t R/L)`` with ``L/R`` below 1/4 of a substep: ``e^-4 = 2 %`` within one substep,
  and the reduction's error on the mechanics is of order ``L/R`` times their rates.
  Explicit RK4 on the full model would need ``dt R/(L RHO)`` substeps instead (a 0.05 ms
  motor: 80 per 10 ms sample, 400 per 50 ms NMPC interval).

- **An L-stable implicit step** (:func:`models.sdirk.sdirk2`, SDIRK of order 2 with Newton's
  method unrolled in the graph) where explicit RK4 would need many more substeps than the rates that
  matter: the regularised friction near rest (``N r mu / (eps J)``, 5.8e7 1/s on a 30 g slider at
  eps = 6.7e-8 m/s) and a law with states (LuGre's bristles, rate-and-state's age) are damped in
  one step whatever ``h lambda``.  Its substep resolves the rig's oscillations (``h |Im lambda| <= ``
  :data:`RHO_IMPLICIT`; a regularised consumer only up to its Nyquist rate ``pi/dt``, what its step can
  see) and any rate at which the friction falls with speed
  (a positive eigenvalue: ``gamma h lambda+ <= `` :data:`UNSTABLE_MAX`, which also keeps each
  stage's equation with one root); it is chosen when it costs fewer operations than RK4 with the
  substeps RK4 would need (CasADi's node counts of one substep of each, with its state Jacobian:
  an implicit substep costs 20-40 RK4 ones).
  No substep count is ever refused for a regularised consumer: the implicit step takes over.

Measured (``benchmarks/bench_stiff_drive.py``: a two-disc rig with a small gear motor,
L/R = 0.05, 0.5 and 5 ms, against CVODES at 1e-10 on the full model) in the README and
``benchmarks/results/stiff_drive.md``.  Every consumer states the decision
(:attr:`Integration.note`), e.g. "current treated quasi-statically: L/R = 0.05 ms << 2.5 ms
substep".
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import casadi as ca

from models.errors import ConfigError
from models.rig.steady import nominal_operating_point
from models.rates import stiff_rates, unstable_rate
from models.sdirk import GAMMA, NEWTON_ITER, NEWTON_SMOOTH, sdirk2

__all__ = ["RHO", "QS_FACTOR", "MAX_SUBSTEPS", "METHODS", "RHO_IMPLICIT", "UNSTABLE_MAX", "FOLD_ABOVE",
           "Integration", "integration", "rk4", "rk4_function"]

#: the integration methods: explicit RK4 with substeps, or the L-stable SDIRK2 (:mod:`models.sdirk`)
METHODS = ("rk4", "sdirk2")
#: the implicit substep keeps ``h |lambda| <= RHO_IMPLICIT`` over the rates at steady sliding
RHO_IMPLICIT = 1.0
#: ... and ``GAMMA h lambda+ <= UNSTABLE_MAX`` over the positive rates (a friction that falls with speed)
UNSTABLE_MAX = 0.5

#: RK4 substeps keep ``h |lambda|max`` at most this
RHO = 2.5
#: the current is quasi-static when ``L/R <= h / QS_FACTOR`` for the substep ``h`` the rest of the rig needs
QS_FACTOR = 4.0
#: more RK4 substeps per step than this is refused (the rig is too stiff for its step)
MAX_SUBSTEPS = 2000
#: more substeps than this: a consumer that needs a step's Jacobians (identification's sample function,
#: the NMPC's stage, the EKF's step) loops over ONE substep (CasADi ``fold``, the chain rule carried along)
#: instead of unrolling them: unrolled, the Jacobians' expression grows with the substeps (22 substeps of
#: a 2-body rig took gcc minutes, 80 of another 7.5 GB of memory; the NMPC's stage on the main scenario
#: was 107,680 instructions); a loop's C code does not grow
FOLD_ABOVE = 4


@dataclass(frozen=True)
class Integration:
    """How a rig is advanced over one step (see the module docstring).

    Attributes
    ----------
    dt : the step [s]
    nsub : RK4 substeps per step
    fast : index of the state treated quasi-statically (a DC motor's current), or None
    rate : the fastest rate the substeps resolve [1/s]
    fast_time : the DC motor's electrical time constant L/R [s] (0 without one)
    note : the decision in words, for messages and descriptions
    """

    dt: float
    nsub: int
    fast: int | None = None
    rate: float = 0.0
    fast_time: float = 0.0
    note: str = ""
    method: str = "rk4"
    stiff: tuple = ()
    band: float = 0.0
    newton: int | None = None
    bracket: tuple = ()

    def __post_init__(self):
        if self.method not in METHODS:
            raise ConfigError(f"integration method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.method != "rk4" and self.fast is not None:
            raise ConfigError("the implicit step integrates a fast current itself: no quasi-static state with it")

    @property
    def h(self) -> float:
        """The substep [s]."""
        return self.dt / self.nsub

    @property
    def quasi_static(self) -> bool:
        return self.fast is not None

    @property
    def implicit(self) -> bool:
        """True for the L-stable implicit step (:func:`models.sdirk.sdirk2`)."""
        return self.method != "rk4"

    @property
    def iterations(self) -> int:
        """Newton iterations per implicit stage: ``newton``, else :data:`models.sdirk.NEWTON_ITER` where a
        contact's friction switches sign through a band or is logarithmic in the speed (``stiff``,
        ``bracket``), :data:`models.sdirk.NEWTON_SMOOTH` where every law is smooth (LuGre)."""
        if self.newton is not None:
            return int(self.newton)
        return NEWTON_ITER if (self.stiff or self.bracket) else NEWTON_SMOOTH

    @property
    def key(self) -> tuple:
        """What a compiled step depends on (cache keys)."""
        return (self.method, self.nsub, self.quasi_static, tuple(self.stiff), tuple(self.bracket),
                self.iterations if self.implicit else 0)

    def advance(self, f, x, u, p, fast_value=None, *, quad=None, dt=None, band=None, residual: bool = False):
        """``x`` after one step of ``xdot = f(x, u, p)`` (symbolic or numeric), input held.

        Parameters
        ----------
        f : callable ``(x, u, p) -> xdot``; ``x`` may be longer than the rig's state (consumers
            augment it), the rig's states first
        fast_value : callable ``(x, u, p) -> value`` of the quasi-static state
            (:meth:`models.rig.RigModel.quasi_static_current` in the consumer's arguments);
            required when :attr:`quasi_static`
        quad : optional ``(x, u, p) -> g``: also return ``int g dt`` over the step (by the method's
            own quadrature; with a quasi-static current ``g`` sees the projected state)
        dt : the step [s] as a number or an expression (default :attr:`dt`; identification's
            sample function takes it as an input)
        band : the friction regularisation [rad/s] as a number or expression (default :attr:`band`)
        residual : also return the implicit stages' largest Newton residual (0 for RK4)

        Returns
        -------
        x_next, or ``(x_next, int g dt)`` with ``quad`` (the residual appended when asked)
        """
        dt = self.dt if dt is None else dt
        if self.implicit:
            if not isinstance(x, (ca.SX, ca.MX)):
                return self._numeric(f, x, u, p, quad, dt, band, residual)
            return self._implicit(f, x, u, p, quad, dt, band, residual)
        if self.fast is None:
            out = rk4(f, x, u, p, dt, self.nsub, quad=quad)
        else:
            if fast_value is None:
                raise ConfigError(f"{self.note}: the consumer must give the quasi-static value of state {self.fast}")
            j = self.fast

            def project(xx):
                return ca.vertcat(xx[:j], fast_value(xx, u, p), xx[j + 1:])

            def g(xx, uu, pp):
                k = f(project(xx), uu, pp)
                return ca.vertcat(k[:j], 0, k[j + 1:])

            qg = None if quad is None else (lambda xx, uu, pp: quad(project(xx), uu, pp))
            out = rk4(g, x, u, p, dt, self.nsub, quad=qg)
            out = project(out) if quad is None else (project(out[0]), out[1])
        if residual:
            return (out, 0.0) if quad is None else (*out, 0.0)
        return out

    def advance_jacobian(self, f, x, u, p, fast_value=None, *, wrt=("x", "u")):
        """``x_next`` (as :meth:`advance`, on symbols) and its Jacobians with respect to the
        arguments named in ``wrt`` (``"x"``, ``"u"``, ``"p"``; each a pure symbol).

        RK4 differentiates its expression; the implicit step takes the implicit function theorem at
        its converged stages (:func:`models.sdirk.sdirk2`'s ``jac``), substep by substep by the chain
        rule, instead of differentiating its unrolled Newton iterations (the same matrices once they
        have converged; a fraction of the operations and of the generated code).

        Returns
        -------
        ``(x_next, [d x_next / d arg for arg in wrt])``
        """
        args = {"x": x, "u": u, "p": p}
        if not self.implicit:
            xn = self.advance(f, x, u, p, fast_value)
            return xn, [ca.jacobian(xn, args[n]) for n in wrt]
        names = tuple(dict.fromkeys(("x", *wrt)))
        xk, D = x, None
        for _ in range(self.nsub):
            out = sdirk2(f, xk, u, p, self.dt / self.nsub, stiff=self.stiff, band=self.band, bracket=self.bracket,
                         newton=self.iterations, jac=names)
            step = dict(zip(names, out[1:]))
            Sx = step["x"]
            if D is None:
                D = dict(step)
            else:
                D = {n: (Sx @ D[n] if n == "x" else Sx @ D[n] + step[n]) for n in names}
            xk = out[0]
        return xk, [D[n] for n in wrt]

    def _implicit(self, f, x, u, p, quad, dt, band, residual):
        """``nsub`` SDIRK2 substeps (:func:`models.sdirk.sdirk2`) on expressions."""
        band = self.band if band is None else band
        q, res = 0, 0
        for _ in range(self.nsub):
            out = sdirk2(f, x, u, p, dt / self.nsub, stiff=self.stiff, band=band, bracket=self.bracket,
                         newton=self.iterations, quad=quad, residual=True)
            x, res = out[0], ca.fmax(res, out[-1])
            if quad is not None:
                q = q + out[1]
        outs = [x] + ([q] if quad is not None else []) + ([res] if residual else [])
        return outs[0] if len(outs) == 1 else tuple(outs)

    def _numeric(self, f, x, u, p, quad, dt, band, residual):
        """The implicit step on numbers: built once on symbols of the arguments' sizes."""
        xs, us, ps = (ca.SX.sym(n, ca.DM(a).numel()) for n, a in (("x", x), ("u", u), ("p", p)))
        out = self._implicit(f, xs, us, ps, quad, dt, band, residual)
        outs = list(out) if isinstance(out, tuple) else [out]
        vals = ca.Function("sdirk2_step", [xs, us, ps], outs)(x, u, p)
        vals = [vals] if not isinstance(vals, (list, tuple)) else list(vals)
        return vals[0] if len(vals) == 1 else tuple(vals)

    def project(self, x, u, p, fast_value):
        """``x`` with the quasi-static state replaced by its value (``x`` itself otherwise)."""
        if self.fast is None:
            return x
        j = self.fast
        return ca.vertcat(x[:j], fast_value(x, u, p), x[j + 1:])


def rk4(f, x, u, p, h, nsub: int, *, quad=None):
    """``nsub`` RK4 steps of size ``h/nsub`` of ``xdot = f(x, u, p)`` (symbolic or numeric); with
    ``quad`` (``(x, u, p) -> g``) also ``int g dt`` by the same stages: ``(x_next, q)``."""
    hs = h / nsub
    q = 0
    for _ in range(nsub):
        k1 = f(x, u, p)
        x2 = x + hs / 2 * k1
        k2 = f(x2, u, p)
        x3 = x + hs / 2 * k2
        k3 = f(x3, u, p)
        x4 = x + hs * k3
        k4 = f(x4, u, p)
        if quad is not None:
            q = q + hs / 6 * (quad(x, u, p) + 2 * quad(x2, u, p) + 2 * quad(x3, u, p) + quad(x4, u, p))
        x = x + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x if quad is None else (x, q)


def _substep_cost(model, eps, imp: "Integration") -> tuple[int, int]:
    """Operations (CasADi SX nodes) of one RK4 substep and one implicit substep of the regularised
    model, with their state Jacobians (what the estimators, identification and the NMPC evaluate)."""
    key = ("substep_cost", eps, imp.key)
    cache = model._fcache
    if key not in cache:
        f = model.ode(model.eps_default if eps is None else eps)
        x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
        out = []
        for step in (rk4(lambda a, b, c: f(a, b, c), x, u, p, 1.0, 1),
                     dataclasses.replace(imp, dt=1.0, nsub=1).advance(lambda a, b, c: f(a, b, c), x, u, p)):
            out.append(ca.Function("cost", [x, u, p], [step, ca.jacobian(step, x)]).n_nodes())
        cache[key] = tuple(out)
    return cache[key]


def _ms(t: float) -> str:
    return f"{t * 1e3:.3g} ms"


def integration(model, params, dt: float, *, u=None, eps: float | None = None, speed: float | None = None,
                min_nsub: int = 1, nsub: int | None = None, rates=(), max_nsub: int | None = MAX_SUBSTEPS,
                where: str = "integration", method: str | None = None) -> Integration:
    """The rule: how ``model`` is advanced over ``dt`` [s] (module docstring).

    Parameters
    ----------
    model : the rig; params : the parameter set the consumer uses
    dt : the consumer's step [s]
    u : (nu,) its largest inputs (default: the rig's nominal operating point)
    eps : its friction regularisation [rad/s]; None for the exact stick/slip plant
    speed : sliding speed [rad/s] of the sliding points (default: the drive's, >= 1 rad/s)
    min_nsub : RK4 substeps at least (a consumer's accuracy floor, e.g. the plant's ``nsub``; the
        implicit step's substep follows from the rates it must resolve)
    nsub : substeps fixed by the consumer's options (identification's ``nsub``, the NMPC's
        ``substeps``): the rule then only decides whether the current is quasi-static, for that
        substep, and says so
    rates : extra rates [1/s] the consumer's own augmented states have (servo lags ``1/tau``)
    max_nsub : refuse more RK4 substeps than this (None: the consumer checks its own limit); a
        regularised consumer (``eps`` given) or a rig whose laws all have states gets the implicit
        step instead of a refusal
    where : prefix of error messages
    method : None (the rule decides), "rk4" or "sdirk2" (forced; "sdirk2" with ``nsub``: that many
        implicit substeps)

    Returns
    -------
    Integration

    Raises
    ------
    ConfigError : the rig is too stiff for the step (more than ``max_nsub`` substeps), or
        its rates are not finite.
    """
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ConfigError(f"{where}: dt must be a finite number > 0 s, got {dt!r}")
    if u is None:
        u = nominal_operating_point(model, params)[0]
    extra = max([float(r) for r in rates], default=0.0)
    lam_full = max(stiff_rates(model, params, u, eps=eps, speed=speed), extra)
    tau_e = model.electrical_time_constant(params)
    if tau_e > 0 and model.drive.limit_refs():
        # a drive held at its supply voltage or current limit has no loop around its current, which then
        # relaxes at R/L alone: a rate the points of steady sliding (the loop acting) do not show.  A zoo
        # rig's plant (R/L = 2867 1/s, the loop's rate 1524 1/s) diverged from rest at 1 ms RK4 substeps
        lam_full = max(lam_full, 1.0 / tau_e)
    if not math.isfinite(lam_full):
        raise ConfigError(f"{where}: the model of rig {model.name!r} has non-finite rates at its operating point "
                          f"(check its parameters)")

    def count(lam):
        if nsub is not None:
            return int(nsub)
        return max(int(min_nsub), int(math.ceil(dt * lam / RHO - 1e-9)), 1)

    n_full = count(lam_full)
    fast, lam, n = None, lam_full, n_full
    note = f"RK4, {n_full} substep(s) of {_ms(dt / n_full)} (fastest rate {lam_full:.3g} 1/s)"
    if nsub is not None:
        note = f"RK4, {n_full} substep(s) of {_ms(dt / n_full)} as asked (fastest rate {lam_full:.3g} 1/s)"
    if tau_e > 0:
        lam_red = max(stiff_rates(model, params, u, eps=eps, speed=speed, reduced=True), extra)
        n_red = count(lam_red)
        stiffer = n_full > n_red or (nsub is not None and dt / nsub * lam_full > RHO >= dt / nsub * lam_red)
        if math.isfinite(lam_red) and stiffer and tau_e <= dt / n_red / QS_FACTOR:
            fast, lam, n = model.current_index, lam_red, n_red
            note = (f"current treated quasi-statically: L/R = {_ms(tau_e)} << {_ms(dt / n_red)} substep "
                    f"(RK4, {n_red} substep(s); the full model would need {n_full})")
        elif stiffer:
            note += f"; set by the motor's L/R = {_ms(tau_e)}"
    if method is not None and method not in METHODS:
        raise ConfigError(f"{where}: method must be one of {', '.join(METHODS)}, got {method!r}")
    smooth = eps is not None or (model.contacts and len(model.stateful_contacts) == len(model.contacts))
    if method == "sdirk2" or (method is None and nsub is None and smooth and n > 1):
        osc, grow = unstable_rate(model, params, u, eps=eps, speed=speed)
        # a regularised consumer (an estimator, a fit, a prediction) sees the rig at its step: it resolves
        # oscillations up to its Nyquist rate pi/dt and leaves faster ones (LuGre's presliding ringing at
        # 1e2-1e3 rad/s) to the implicit step's damping; the plant resolves every one
        lam_i = max(min(osc, math.pi / dt) if eps is not None else osc, extra)
        if not (math.isfinite(osc) and math.isfinite(grow)):
            raise ConfigError(f"{where}: the model of rig {model.name!r} has non-finite rates at its operating point "
                              f"(check its parameters)")
        # (``min_nsub`` is RK4's accuracy floor, an event's resolution in the exact plant: not the
        # implicit step's, whose substep follows from the rates it must resolve)
        n_imp = int(nsub) if nsub is not None else max(int(math.ceil(dt * lam_i / RHO_IMPLICIT - 1e-9)),
                                                       int(math.ceil(dt * GAMMA * grow / UNSTABLE_MAX - 1e-9)), 1)
        stiff = tuple(idx for i, idx in enumerate(model.contacts) if i not in model.stateful_contacts) \
            if eps is not None else ()
        brk = tuple(model.contacts[i] for i in model.stateful_contacts if model.rest_free(i))
        imp = Integration(float(dt), n_imp, None, float(max(lam_i, grow)), float(tau_e), "", "sdirk2", stiff,
                          float(eps) if eps is not None else 0.0, bracket=brk)
        cost_rk4, cost_imp = _substep_cost(model, eps, imp)
        if method == "sdirk2" or n * cost_rk4 > n_imp * cost_imp or (max_nsub is not None and n > max_nsub):
            # RK4's own count, whatever ``nsub`` asked of the implicit step (a fit's raise asks 6)
            n_rk4 = max(int(min_nsub), int(math.ceil(dt * lam_full / RHO - 1e-9)), 1)
            note = (f"implicit SDIRK2 (L-stable, order 2, {imp.iterations} Newton iterations a stage), {n_imp} "
                    f"substep(s) of {_ms(dt / n_imp)}: explicit RK4 would need {n_rk4} (fastest rate {lam_full:.3g} "
                    f"1/s, {n_rk4 * cost_rk4 / max(n_imp * cost_imp, 1):.3g} times the operations); the substep resolves "
                    f"oscillations up to {lam_i:.3g} rad/s and a friction fall of {grow:.3g} 1/s")
            return dataclasses.replace(imp, note=note)
    if max_nsub is not None and n > max_nsub:
        raise ConfigError(f"{where}: rig {model.name!r} needs {n} RK4 substeps per {dt:g} s step (fastest rate "
                          f"{lam:.3g} 1/s); more than {max_nsub}: shorten the step or check the rig's stiffness")
    return Integration(float(dt), int(n), fast, float(lam), float(tau_e), note)


def rk4_function(model, dt: float, nsub: int, eps: float | None = None, *, name: str | None = None,
                 expand: bool = True) -> ca.Function:
    """Discrete-time model ``x+ = F(x, u, p)`` over ``dt`` [s] with ``nsub`` RK4 substeps.

    Parameters
    ----------
    model : models.rig.RigModel
    dt : sample period [s], > 0
    nsub : substeps per sample, >= 1
    eps : friction regularisation [rad/s] (model default if None)
    expand : build in SX (fast to evaluate, good for Jacobians) instead of MX
    """
    if not dt > 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    if int(nsub) != nsub or nsub < 1:
        raise ConfigError(f"nsub must be an integer >= 1, got {nsub}")
    f = model.ode(eps)
    kind = ca.SX if expand else ca.MX
    x = kind.sym("x", model.nx)
    u = kind.sym("u", model.nu)
    p = kind.sym("p", model.n_p)
    xn = rk4(lambda a, b, c: f(a, b, c), x, u, p, dt, int(nsub))
    return ca.Function(name or f"{model.cname}_rk4", [x, u, p], [xn], ["x", "u", "p"], ["x_next"])
