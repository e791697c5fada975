"""The estimation model the EKF and the MHE share, built from any rig.

:func:`build_estimation_model` turns a :class:`models.rig.RigModel`, its parameters, the DAQ
period and :class:`estimators.online.options.EKFOptions` into an :class:`EstimationModel`:
a discrete-time augmented model ``x+ = F(x, u, p)``, a measurement function
``y = h(x, u, p)`` (NOT linear in the state: the filters linearise it), the map from raw log
channels to the internal measurements, and the noise covariances and prior.

State (``EstimationModel.names``)
---------------------------------
The rig's states (``model.states``, e.g. rig3 ``twist_shaft1, twist_shaft2, omega_R1,
omega_R2, omega_R3, current, pi_integral``), then, in this order:

- ``zero:<twist>`` [rad] (``angles = "zeroed"``): the twist at encoder power-on.  Incremental
  encoders read 0 at power-on, so an encoder difference measures the twist combination
  between the two encoders MINUS its value at power-on.  These are constants whose prior is
  the initial-twist prior, fully correlated with it (the offset IS the initial twist).
  ``angles = "absolute"`` drops them (encoders referenced to the untwisted shaft).
- ``load:<contact>`` [-]: a random-walk factor on that contact's friction torque (absorbs a
  friction-level mismatch and its drift, the contact's "formation"); prior 1.
- ``offset:<channel>`` [channel unit], ``gain:<channel>`` [-]: random walks replacing the rig's
  parameters ``<channel>_offset`` / ``<channel>_gain`` of a torque or speed sensor (they enter
  ``h``) or of a load cell (they enter the input correction ``N = (reading - offset)/gain``,
  :meth:`models.rig.RigModel.input_from_measured`); prior the parameter's value.
- ``lag<d>:<state>``: the rig's states ``d`` samples ago, when a channel's sensor in the
  estimator's rig file has ``delay = d > 0``; that channel is then ``h`` of the lagged state
  (and of the input then), which is exact for instantaneous channels.

Measurements
------------
- Encoder angles enter as differences of consecutive encoders (``theta1 - theta2``,
  ``theta2 - theta3``): an encoder's angle is the reference angle plus the twists on its path
  through the rig's spring tree (:meth:`models.rig.RigModel.angle`), so a difference is a
  combination of twists and needs no absolute angle.  Consecutive differences share an
  encoder, so their quantisation errors are correlated; they are whitened (Cholesky of their
  covariance) so that the sequential scalar updates of the filters are exact.
- Speeds (an encoder's backward difference, or a speed sensor) and torque sensors are the
  rig's own output function (:meth:`models.rig.RigModel.outputs`) at the state and the
  input of the sample that ended.  For rig3's ``motor_torque`` that is the REACTION torque
  of the free-mounted motor and gearbox, ``T_em - eta (eta - 1) Jm omega_R3'``, which contains
  the acceleration and a tanh: nonlinear in the state.
- Load cells are inputs, never measurements: ``update(t, measurement, u)`` gets the logged
  forces in ``u`` and the model corrects them for the cells' gain and offset.
- Noise: :func:`models.sensors.channel_variance` (encoder angle ``q^2/12``, encoder speed
  ``2 q^2/12/dt^2``, others ``(noise noise_scale)^2``).  The backward-difference speed is the
  mean speed over the last sample and its noise is MA(1); the model reads the speed at the
  sample and treats the noise as white (a documented approximation).

Process noise (per DAQ sample; :mod:`estimators.online.covariance`, with the prior and the
bounds): an unmodelled torque of standard deviation ``q_torque`` on every body (``var(omega_b) =
(q_torque dt / J_b)^2``, ``J_b`` the body's total inertia, a DC motor's ``ratio^2 Jm``
included), ``q_current`` on a DC motor's current, ``q_twist`` on the twists, none on the PI
integral (it integrates known signals) nor on ``zero:`` and ``lag`` states, and random walks
``q_load^2 dt``, ``q_offset^2 dt``, ``q_gain^2 dt``.  On top, a body with friction that is
(nearly) at rest gets an unknown torque of ``q_stick`` times its contacts' static friction
torque (weighted by ``1 - tanh^2(omega/eps)``, so only within about ``eps`` of rest): in stick
the friction is a constraint force anywhere within the static limit, while the regularised model
makes it a steep function of a creep speed that the real contact does not have.  Trusting that
creep (``q_stick = 0``) made the EKF converge to a wrong twist at power-on on our exact
stick/slip plant (0.2-0.7 rad off, benchmarks).

Defaults, and why
-----------------
Measured on rig3 (``benchmarks/results/estimators.md``: our exact stick/slip plant, a
structurally different plant, the independent simulator; DAQ powered on in stick-slip on a
twisted shaft):

- ``channels``: every encoder angle and speed, speed sensor and torque sensor of the rig
  (rig3: ``theta1..3, omega1..3, motor_torque``); load cells are inputs.  A real rig has them.
- ``angles = "zeroed"``: incremental encoders read 0 at power-on whatever the twist then; an
  estimator that assumed an untwisted shaft is off by that twist for ever (the FD baseline,
  by 0.18 / 0.28 rad).
- ``augment = ["load:<contact of the objective body>", "offset:<each torque channel>"]``
  (rig3: ``load:pin1, offset:motor_torque``):

  - ``load:pin1``: the regularised friction never matches a real contact's level, and a
    contact's friction drifts as it wears; the factor absorbs both.
  - ``offset:motor_torque``: a real load cell's zero drifts.  An unmodelled 0.05 N m offset
    put the twist of shaft 2 off by 0.14 rad (``0.05 / k2``) while the filter claimed 1 mrad
    (NEES 1.7e4): a confident wrong answer.  With the state: 8 / 27 mrad, offset found.
  - The price, stated by the observability check: with the offset state the torque channel no
    longer gives the twist's absolute level, so the twist at power-on, the load factor and the
    offset trade off exactly at STEADY sliding and separate only through the friction's
    variation (stick-slip, speed changes).  In stick-slip the twist RMSE is 1-2 % of its range
    (4 / 12 mrad on our plant, against 1.3 / 1.3 mrad without the offset state); at steady
    sliding the level set at power-on is not corrected (benchmark case (e)).  On a rig known
    to have a stable, tared torque channel, ``augment = ["load:pin1"]`` is better.
- ``q_stick = 2``: in stick the friction is a constraint force, so a body within ``eps`` of
  rest gets an unknown torque of twice its static friction.  Trusting the regularised creep
  instead (``q_stick = 0``) made the EKF converge to a twist 0.2-0.7 rad off on our plant.
- ``q_load = 0.02 /sqrt(s)`` (a friction level that may drift 15 % in a minute) and
  ``p0_offset = 0.05 N m`` (a roughly tared cell): smaller values tie the twist closer to the
  prior and hurt when the plant does have an offset; larger ones let the weakly observable
  direction wander (measured trade-off, benchmarks).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from models import friction as fr
from models.errors import ConfigError
from models.params import ParameterSet
from models.rig import RigModel
from estimators.online.channels import angle_combination, angle_node, resolve_augment, resolve_channels, state_units
from models.sensors import FLOOR, SensorOptions, channel_variance
from models.discretise import FOLD_ABOVE, Integration, integration
from estimators.online.options import for_rig
from estimators.online.projection import projection
from estimators.online.covariance import prior, process_variances, state_bounds

__all__ = ["EstimationModel", "build_estimation_model", "rig_rhs"]

# ----------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class EstimationModel:
    """The augmented discrete-time model of both filters (module docstring).

    Attributes
    ----------
    model : the rig; params : its parameter set; dt : DAQ period [s]
    names, units : estimator states and their SI units
    n_rig : the first ``n_rig`` states are the rig's (``model.states``)
    channels : raw log channels read from a measurement dict, in order
    meas_names : internal measurements (whitened angle differences, then the other channels)
    delay : samples of input history the model needs (``uh`` holds ``u_k, u_{k-1}, ...``)
    F : Function ``(x, uh, p) -> x_next`` over one sample (RK4 with substeps)
    FA : Function ``(x, uh, p) -> (x_next, A = dx_next/dx)``, a loop over one substep carrying the chain
        rule (CasADi ``fold``) where the step has more than :data:`~models.discretise.FOLD_ABOVE`
        substeps (the EKF's prediction: C code that does not grow with the substeps); None: ``F`` and
        its Jacobian as one expression
    integration : how ``F`` integrates the rig (:func:`models.discretise.integration`: substeps,
        a fast motor's current quasi-static); its ``note`` says so
    h : Function ``(x, uh, p) -> y`` internal measurements
    to_internal : Function ``(y_raw, m_raw) -> (y, m)`` raw channels and their masks (1 present,
        0 missing) to internal measurements and masks
    dep : (n_meas, n_channels) bool: which raw channels each internal measurement uses
    q : (nx,) process-noise variances per sample (the constant part)
    stick : Function ``(x, uh, p) -> dq``: the state-dependent part, the unknown friction of
        bodies at rest (``q_stick``); the total is ``q + dq``
    stick_speed : [rad/s] the model's friction regularisation ``eps``: a contact body slower
        than this is "in stick" (the observability analysis treats its friction as unknown)
    r : (n_meas,) measurement-noise variances
    x0, P0 : prior; lb, ub : state bounds (MHE)
    project : Function ``(x, uh, p) -> x`` the EKF applies to its corrected mean: a DC motor's PI
        integral into what its anti-windup can reach, the load factors into ``[lb, ub]``
    p : (n_p,) parameter vector (the rig's order)
    """

    model: RigModel
    params: ParameterSet
    dt: float
    names: tuple
    units: tuple
    n_rig: int
    channels: tuple
    meas_names: tuple
    delay: int
    F: ca.Function
    h: ca.Function
    to_internal: ca.Function
    dep: np.ndarray
    q: np.ndarray
    stick: ca.Function
    stick_speed: float
    r: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    p: np.ndarray
    angles: str = "zeroed"
    augment: tuple = ()
    integration: Integration | None = None
    project: ca.Function | None = None
    FA: ca.Function | None = None

    @property
    def nx(self) -> int:
        return len(self.names)

    @property
    def ny(self) -> int:
        return len(self.meas_names)

    @property
    def nu(self) -> int:
        return self.model.nu

    @property
    def nuh(self) -> int:
        """Length of the input history vector ``uh``."""
        return self.model.nu * (self.delay + 1)

    @property
    def twist_names(self) -> tuple[str, ...]:
        return tuple(n for n in self.model.states if n.startswith("twist_"))

    def index(self, name: str) -> int:
        return self.names.index(name)

    def full_state(self, x_rig) -> np.ndarray:
        """An estimator state from rig states: augmented states at their prior values
        (``zero:`` and ``lag`` states follow the given rig state)."""
        x_rig = np.asarray(x_rig, float).ravel()
        x = self.x0.copy()
        x[:self.n_rig] = x_rig
        for j, n in enumerate(self.names[self.n_rig:], start=self.n_rig):
            kind, _, target = n.partition(":")
            if kind == "zero" or kind.startswith("lag"):
                x[j] = x_rig[self.model.states.index(target)]
        return x


def rig_rhs(model: RigModel, x, u, P: dict, eps: float, factors: dict):
    """The rig's regularised state derivative with friction factors per contact.

    Identical to ``model.ode(eps)`` when every factor is 1 (tests check it); a factor scales
    its contact's friction torque, not the inertia a contact may add.
    """
    Tc = [model.contact_friction(i, x[idx], u, P, eps, factors=factors, x=x) for i, idx in enumerate(model.contacts)]
    s = [fr.smooth_sign(x[idx], eps) for idx in model.contacts]
    return ca.vertcat(*model.dynamics(x, u, P, Tc, s))


def _check_dt(dt, where):
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0):
        raise ConfigError(f"{where}.dt must be a finite number > 0 s, got {dt!r}")
    return float(dt)


def build_estimation_model(model: RigModel, params: ParameterSet, options, dt: float,
                           sensors: SensorOptions = SensorOptions(), x0=None,
                           where: str = "estimator") -> EstimationModel:
    """Build the augmented model, its covariances and prior (module docstring).

    Parameters
    ----------
    model : the rig the estimator believes
    params : its parameter set
    options : :class:`estimators.online.options.EKFOptions` (or MHEOptions)
    dt : DAQ period [s]
    sensors : sensor settings (noise scale, quantisation)
    x0 : initial guess, ``model.states`` order (nx_rig) or the full estimator state; None:
        at rest (rig states 0, augmented states at their nominal values)
    where : prefix of error messages

    Raises
    ------
    ConfigError : one line naming ``<where>.<field>``.
    """
    options = for_rig(options, model, params)      # the unit-carrying defaults from the rig
    if not isinstance(model, RigModel):
        raise ConfigError(f"{where}.model must be a RigModel, got {type(model).__name__}")
    model.check_params(params, f"{where}.params")
    dt = _check_dt(dt, where)
    chans = resolve_channels(model, options, where)
    aug = resolve_augment(model, options, chans, where)
    nxr, nu = model.nx, model.nu
    P_num = dict(zip(model.param_names, np.asarray(params.vector(), float)))

    # ---- measurement layout
    angle_ch = [c for c in chans if angle_node(model, c) is not None]
    other_ch = [c for c in chans if c not in angle_ch]
    combs = {c: angle_combination(model, angle_node(model, c)) for c in angle_ch}
    n_tw = sum(1 for s in model.states if s.startswith("twist_"))
    zero_tw = []
    if options.angles == "zeroed" and angle_ch:
        used = np.zeros(nxr, bool)
        for a, b in zip(angle_ch[:-1], angle_ch[1:]):
            used |= np.abs(combs[a] - combs[b]) > 0
        zero_tw = [model.states[j] for j in range(n_tw) if used[j]]
    delays = {c: model.sensor_of(c).delay for c in chans}
    D = max(delays.values(), default=0)

    names = list(model.states)
    names += [f"zero:{n}" for n in zero_tw]
    names += [a for a in aug if a.startswith("load:")]
    names += [a for a in aug if a.startswith(("offset:", "gain:"))]
    names += [f"lag{d}:{n}" for d in range(1, D + 1) for n in model.states]
    names = tuple(names)
    nx = len(names)
    idx = {n: i for i, n in enumerate(names)}

    x = ca.SX.sym("x", nx)
    uh = ca.SX.sym("uh", nu * (D + 1))
    p = ca.SX.sym("p", model.n_p)
    P = model.unpack(p)
    # augmented sensor offsets and gains replace their parameters everywhere they are used
    Pm = dict(P)
    for a in aug:
        kind, _, target = a.partition(":")
        if kind in ("offset", "gain"):
            Pm[getattr(model.sensor_of(target), kind).name] = x[idx[a]]
    factors = {a.partition(":")[2]: x[idx[a]] for a in aug if a.startswith("load:")}

    def u_at(d):
        return model.input_from_measured(uh[d * nu:(d + 1) * nu], Pm)

    def x_rig_at(d):
        if d == 0:
            return x[:nxr]
        return ca.vertcat(*[x[idx[f"lag{d}:{n}"]] for n in model.states])

    # ---- dynamics: RK4 of the rig with the friction factors; augmented states held; lags shift
    xr_s, ur_s, fa_s = ca.SX.sym("xr", nxr), ca.SX.sym("ur", nu), ca.SX.sym("fa", max(len(factors), 1))
    ps = ca.SX.sym("p", model.n_p)
    fac = {c: fa_s[i] for i, c in enumerate(factors)}
    f_rhs = ca.Function("rhs", [xr_s, ur_s, ps, fa_s], [rig_rhs(model, xr_s, ur_s, model.unpack(ps), options.eps, fac)])
    fvec = ca.vertcat(*factors.values()) if factors else ca.SX.zeros(1)
    u0 = ca.vertcat(*u_at(0))
    integ = integration(model, params, dt, eps=options.eps, min_nsub=int(options.nsub), where=where)
    xr_next = integ.advance(lambda a, b, c: f_rhs(a, b, c, fvec), x[:nxr], u0, p,
                            lambda a, b, c: model.quasi_static_current(a, b, model.unpack(c)))
    nxt = [xr_next]
    if nx > nxr:
        held = [x[idx[n]] for n in names[nxr:] if not n.startswith("lag")]
        if held:
            nxt.append(ca.vertcat(*held))
        for d in range(1, D + 1):
            nxt.append(x_rig_at(d - 1))
    F = ca.Function(f"{model.cname}_est_F", [x, uh, p], [ca.vertcat(*nxt)], ["x", "uh", "p"], ["x_next"])
    FA = None
    if integ.nsub > FOLD_ABOVE:
        FA = _folded_step(model, integ, f_rhs, fvec, u0, x, uh, p, nxr, ca.vertcat(*nxt[1:]) if nx > nxr else None)

    # ---- measurements
    ys, meas, dep_rows = [], [], []
    ci = {c: i for i, c in enumerate(chans)}
    yr, mr = ca.SX.sym("y_raw", len(chans)), ca.SX.sym("m_raw", len(chans))
    yi, mi = [], []
    if angle_ch:
        pairs = list(zip(angle_ch[:-1], angle_ch[1:]))
        var = {c: channel_variance(model, c, dt, sensors) for c in angle_ch}
        T = np.zeros((len(pairs), len(angle_ch)))
        for k in range(len(pairs)):
            T[k, k], T[k, k + 1] = 1.0, -1.0
        Rd = T @ np.diag([var[c] for c in angle_ch]) @ T.T
        Linv = np.linalg.inv(np.linalg.cholesky(Rd))
        hd = []
        for a, b in pairs:
            da = delays[a]
            if da != delays[b]:
                raise ConfigError(f"{where}.channels: encoder angles {a!r} and {b!r} have different delays "
                                  f"({da} and {delays[b]} samples); their difference is not one instant's twist")
            cvec = combs[a] - combs[b]
            xr_d = x_rig_at(da)
            e = 0
            for j in np.flatnonzero(cvec):
                tw = xr_d[j] - (x[idx[f"zero:{model.states[j]}"]] if f"zero:{model.states[j]}" in idx else 0)
                e = e + float(cvec[j]) * tw
            hd.append(e)
        ys.append(ca.mtimes(ca.DM(Linv), ca.vertcat(*hd)))
        draw = ca.vertcat(*[yr[ci[a]] - yr[ci[b]] for a, b in pairs])
        yi.append(ca.mtimes(ca.DM(Linv), draw))
        for k, (a, b) in enumerate(pairs):
            meas.append(f"{a}-{b}")
            used = {c for kk in range(k + 1) if abs(Linv[k, kk]) > 0 for c in pairs[kk]}
            mi.append(_prod([mr[ci[c]] for c in angle_ch if c in used]))
            dep_rows.append([c in used for c in chans])
    if other_ch:
        for c in other_ch:
            d = delays[c]
            out = model.outputs(x_rig_at(d), ca.vertcat(*u_at(d)), Pm, 0)
            ys.append(out[c])
            meas.append(c)
            yi.append(yr[ci[c]])
            mi.append(mr[ci[c]])
            dep_rows.append([cc == c for cc in chans])
    h = ca.Function(f"{model.cname}_est_h", [x, uh, p], [ca.vertcat(*ys)], ["x", "uh", "p"], ["y"])
    to_internal = ca.Function(f"{model.cname}_est_to_internal", [yr, mr], [ca.vertcat(*yi), ca.vertcat(*mi)],
                              ["y_raw", "m_raw"], ["y", "m"])
    r = np.array([1.0] * (len(angle_ch) - 1 if angle_ch else 0)
                 + [channel_variance(model, c, dt, sensors) for c in other_ch])
    r = np.maximum(r, FLOOR)

    # ---- stick: in stick the friction is a constraint force, not the regularised law's creep
    dq = [ca.SX(0)] * nx
    if options.q_stick > 0:
        un = u_at(0)
        for i, jdx in enumerate(model.contacts):
            if i in model.stateful_contacts:
                continue        # a law with states models stick itself (presliding, creep): no unknown torque
            Ts = 0
            for cname in model.contact_names[i]:
                tp, tm = model.law(cname).static_limits(*model.contact_args(cname, P, un))
                t_s = 0.5 * (ca.fabs(tp) + ca.fabs(tm))
                Ts = Ts + t_s     # the nominal limit: a load factor near 0 must not switch this off
            J = model.inertia(model.contact_bodies[i], P)
            sech2 = 1 - ca.tanh(x[jdx] / options.eps) ** 2
            dq[jdx] = (options.q_stick * Ts * dt / J) ** 2 * sech2
    stick = ca.Function(f"{model.cname}_est_stick", [x, uh, p], [ca.vertcat(*dq)], ["x", "uh", "p"], ["dq"])

    # ---- projection: a DC motor's PI integral within what its anti-windup lets it reach, the load
    # factors within the MHE's bounds (a negative friction factor, with a twist of the wrong sign
    # along the unobservable twist/zero/load direction, made the NMPC run mismatch_p40 42 % fast)
    project = projection(model, names, *state_bounds(names), x, uh, p, u_at(0), Pm)

    # ---- covariances, prior, bounds
    q = process_variances(model, names, P_num, dt, options)
    x0v, P0 = prior(model, names, idx, P_num, options, x0, where, model.friction_state_scale(params))
    lb, ub = state_bounds(names)
    return EstimationModel(model, params, dt, names, state_units(model, names), nxr, chans, tuple(meas), D, F, h,
                           to_internal, np.array(dep_rows, bool).reshape(len(meas), len(chans)), q, stick, float(options.eps), r, x0v, P0, lb,
                           ub, np.array([P_num[n] for n in model.param_names]), options.angles, aug, integ,
                           project, FA)


def _folded_step(model, integ, f_rhs, fvec, u0, x, uh, p, nxr: int, rest) -> ca.Function:
    """``(x, uh, p) -> (x_next, A)``: the rig's ``integ.nsub`` substeps as a ``fold`` over one substep
    and its Jacobian, ``Z' = J_r Z + J_x`` with ``Z = d xr / dx`` from ``[I, 0]`` (the inputs ``u0``
    and the load factors ``fvec`` depend on the augmented states, held over the sample); ``rest``
    (held states and lags, linear in ``x``) or None follows."""
    nx = x.numel()
    one = dataclasses.replace(integ, dt=integ.dt / integ.nsub, nsub=1)
    xr = ca.SX.sym("xr", nxr)
    xr1 = one.advance(lambda a, b, c: f_rhs(a, b, c, fvec), xr, u0, p,
                      lambda a, b, c: model.quasi_static_current(a, b, model.unpack(c)))
    Z = ca.SX.sym("Z", nxr, nx)
    Zn = ca.jacobian(xr1, xr) @ Z + ca.jacobian(xr1, x)
    sub = ca.Function(f"{model.cname}_est_substep", [ca.vertcat(xr, ca.vec(Z)), x, uh, p],
                      [ca.vertcat(xr1, ca.vec(Zn))], ["z", "x", "uh", "p"], ["z_next"])
    xM, uhM, pM = ca.MX.sym("x", nx), ca.MX.sym("uh", uh.numel()), ca.MX.sym("p", p.numel())
    n = integ.nsub
    z0 = ca.vertcat(xM[:nxr], ca.vec(ca.horzcat(ca.MX.eye(nxr), ca.MX(nxr, nx - nxr))))
    zN = sub.fold(n)(z0, ca.repmat(xM, 1, n), ca.repmat(uhM, 1, n), ca.repmat(pM, 1, n))
    xrN, ZN = zN[:nxr], ca.reshape(zN[nxr:], nxr, nx)
    if rest is not None:
        tail = ca.Function(f"{model.cname}_est_rest", [x], [rest, ca.jacobian(rest, x)])
        r, Jr = tail(xM)
        xrN, ZN = ca.vertcat(xrN, r), ca.vertcat(ZN, Jr)
    return ca.Function(f"{model.cname}_est_FA", [xM, uhM, pM], [xrN, ca.densify(ZN)], ["x", "uh", "p"],
                       ["x_next", "A"])


def _prod(terms):
    out = terms[0]
    for t in terms[1:]:
        out = out * t
    return out
