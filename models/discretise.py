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

Measured (``benchmarks/bench_stiff_drive.py``: a two-disc rig with a small gear motor,
L/R = 0.05, 0.5 and 5 ms, against CVODES at 1e-10 on the full model) in the README and
``benchmarks/results/stiff_drive.md``.  Every consumer states the decision
(:attr:`Integration.note`), e.g. "current treated quasi-statically: L/R = 0.05 ms << 2.5 ms
substep".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from models.errors import ConfigError
from models.rig.steady import nominal_operating_point

__all__ = ["RHO", "QS_FACTOR", "MAX_SUBSTEPS", "Integration", "integration", "rk4", "rk4_function",
           "stiff_rates", "rate_jacobian"]

#: RK4 substeps keep ``h |lambda|max`` at most this
RHO = 2.5
#: the current is quasi-static when ``L/R <= h / QS_FACTOR`` for the substep ``h`` the rest of the rig needs
QS_FACTOR = 4.0
#: more RK4 substeps per step than this is refused (the rig is too stiff for its step)
MAX_SUBSTEPS = 2000


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

    @property
    def h(self) -> float:
        """The substep [s]."""
        return self.dt / self.nsub

    @property
    def quasi_static(self) -> bool:
        return self.fast is not None

    def advance(self, f, x, u, p, fast_value=None):
        """``x`` after one step of ``xdot = f(x, u, p)`` (symbolic or numeric), input held.

        Parameters
        ----------
        f : callable ``(x, u, p) -> xdot``; ``x`` may be longer than the rig's state (consumers
            augment it), the rig's states first
        fast_value : callable ``(x, u, p) -> value`` of the quasi-static state
            (:meth:`models.rig.RigModel.quasi_static_current` in the consumer's arguments);
            required when :attr:`quasi_static`
        """
        if self.fast is None:
            return rk4(f, x, u, p, self.dt, self.nsub)
        if fast_value is None:
            raise ConfigError(f"{self.note}: the consumer must give the quasi-static value of state {self.fast}")
        j = self.fast

        def project(xx):
            return ca.vertcat(xx[:j], fast_value(xx, u, p), xx[j + 1:])

        def g(xx, uu, pp):
            k = f(project(xx), uu, pp)
            return ca.vertcat(k[:j], 0, k[j + 1:])

        return project(rk4(g, x, u, p, self.dt, self.nsub))

    def project(self, x, u, p, fast_value):
        """``x`` with the quasi-static state replaced by its value (``x`` itself otherwise)."""
        if self.fast is None:
            return x
        j = self.fast
        return ca.vertcat(x[:j], fast_value(x, u, p), x[j + 1:])


def rk4(f, x, u, p, h, nsub: int):
    """``nsub`` RK4 steps of size ``h/nsub`` of ``xdot = f(x, u, p)`` (symbolic or numeric)."""
    hs = h / nsub
    for _ in range(nsub):
        k1 = f(x, u, p)
        k2 = f(x + hs / 2 * k1, u, p)
        k3 = f(x + hs / 2 * k2, u, p)
        k4 = f(x + hs * k3, u, p)
        x = x + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def rate_jacobian(model, eps: float, reduced: bool = False) -> ca.Function:
    """``J(x, u, p)`` of the regularised model, or of the model with the current quasi-static
    (cached on the model)."""
    key = ("stiff_jac", eps, reduced)
    cache = model._fcache
    if key not in cache:
        f = model.ode(eps)
        x, u, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
        if reduced:
            j = model.current_index
            xq = ca.vertcat(x[:j], model.quasi_static_current(x, u, model.unpack(p)), x[j + 1:])
            xd = f(xq, u, p)
            xd = ca.vertcat(xd[:j], 0, xd[j + 1:])
        else:
            xd = f(x, u, p)
        cache[key] = ca.Function(f"{model.cname}_stiff_jac", [x, u, p], [ca.jacobian(xd, x)])
    return cache[key]


def stiff_rates(model, params, u, *, eps: float | None = None, speed: float | None = None,
                reduced: bool = False) -> float:
    """The largest eigenvalue magnitude [1/s] of the model's Jacobian over the points of the rule.

    Parameters
    ----------
    model : the rig; params : its ParameterSet (or a parameter vector)
    u : (nu,) inputs (the consumer's largest; forces at their largest)
    eps : friction regularisation [rad/s] of a regularised consumer: every contact body at rest
        or sliding at ``speed`` counts; None (the exact stick/slip plant): only sliding, at the
        model's default regularisation (whose sliding slope is the law's own)
    speed : the sliding speed [rad/s] of every body (default: the drive's, at least 1 rad/s; a torque
        drive's: the speed its torque sustains, or the rig's nominal speed where it sustains none)
    reduced : with the DC motor's current quasi-static
    """
    pv = np.asarray(params.vector() if hasattr(params, "vector") else params, float)
    u = np.asarray(u, float).ravel()
    J = rate_jacobian(model, model.eps_default if eps is None else float(eps), reduced)
    try:
        with np.errstate(all="ignore"):
            xs = np.asarray(model.sliding_guess(u, params), float)
    except Exception:  # noqa: BLE001 - any finite point will do for a rate estimate
        xs = np.zeros(model.nx)
    xs = np.where(np.isfinite(xs), xs, 0.0)
    if speed is None:
        speed = 1.0
        if model.drive.sets_speed:
            speed = max(abs(float(u[model.inputs.index(model.drive_input)])), 1.0)
        elif model.contacts:
            # the speed the torque sustains; where none does, the guess runs off (100 x the rig's nominal
            # speed and more): the rig's nominal speed then
            w, w_nom = abs(float(xs[model.contacts[0]])), abs(float(model.nominal_speed()))
            speed = max(w if w <= 100 * max(w_nom, 1.0) else w_nom, 1.0)
    # every body at the sliding speed (the guess has them at one speed, its own): a torque the friction
    # holds at every speed has no steady sliding and the guess runs off (a lead screw under an axial load
    # its drive torque cannot turn: 6e8 rad/s), and the springs' dampers between a body at that speed and
    # a contact body at ``speed`` then gave the lead screw's speed-dependent inertia a rate of 2e8 1/s
    for b in model.bodies:
        xs[model.speed_index(b)] = speed
    nc = min(len(model.contacts), 4)
    combos = [2 ** nc - 1] if eps is None else range(2 ** nc)
    lam = 0.0
    for combo in combos:
        xx = xs.copy()
        for i in range(nc):
            xx[model.contacts[i]] = speed if combo >> i & 1 else 0.0
        A = np.array(J(xx, u, pv), float)
        if not np.all(np.isfinite(A)):
            return math.inf
        ev = np.linalg.eigvals(A) if A.size else np.zeros(0)
        lam = max(lam, float(np.max(np.abs(ev))) if ev.size else 0.0)
    return lam


def _ms(t: float) -> str:
    return f"{t * 1e3:.3g} ms"


def integration(model, params, dt: float, *, u=None, eps: float | None = None, speed: float | None = None,
                min_nsub: int = 1, nsub: int | None = None, rates=(), max_nsub: int | None = MAX_SUBSTEPS,
                where: str = "integration") -> Integration:
    """The rule: how ``model`` is advanced over ``dt`` [s] (module docstring).

    Parameters
    ----------
    model : the rig; params : the parameter set the consumer uses
    dt : the consumer's step [s]
    u : (nu,) its largest inputs (default: the rig's nominal operating point)
    eps : its friction regularisation [rad/s]; None for the exact stick/slip plant
    speed : sliding speed [rad/s] of the sliding points (default: the drive's, >= 1 rad/s)
    min_nsub : substeps at least (a consumer's accuracy floor, e.g. the plant's ``nsub``)
    nsub : substeps fixed by the consumer's options (identification's ``nsub``, the NMPC's
        ``substeps``): the rule then only decides whether the current is quasi-static, for that
        substep, and says so
    rates : extra rates [1/s] the consumer's own augmented states have (servo lags ``1/tau``)
    max_nsub : refuse more substeps than this (None: the consumer checks its own limit)
    where : prefix of error messages

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
