"""Extended Kalman filter on any rig: one fused, compiled CasADi step per DAQ sample.

The filter runs on the estimation model of :mod:`estimators.online.model` (the rig's
regularised model, RK4 with substeps, augmented states).  Predict and correct are ONE
CasADi Function ``ekf_step(x, P, uh, y, m, p, q, r) -> (x_next, P_next)``:

- predict: ``x- = F(x, uh)``, ``P- = A P A' + diag(q + dq(x))``, ``A = dF/dx`` (exact AD of
  the discretisation; ``dq`` the unknown friction of bodies in stick, see the model);
- correct: the measurement function is nonlinear (the reaction torque holds the
  acceleration and a tanh), so it is linearised at the predicted state, ``C = dh/dx(x-)``,
  and the internal measurements (whitened, so independent) are applied as sequential
  scalar updates ``innov_j = y_j - h_j(x-) - C_j (x - x-)``, each weighted by its mask
  ``m_j`` (0 skips the channel exactly: zero gain).  This equals the batch EKF update at
  ``x-``.

``uh`` is the input history ``[u_k, u_{k-1}, ...]`` (only ``u_k`` unless a channel is
delayed); the filter keeps it.

Observability: at construction the filter checks its model along a short simulated
trajectory (:meth:`EKF.observability`, see :mod:`estimators.online.observability`); if the
twist is not observable every estimate says so (``Status.WARNING`` and the report's one-line
message), and :meth:`EKF.observability_along` checks a logged trajectory.

Speed and one implementation: ``compile=True`` runs the whole update -- the input history, the
masks, the first sample's speeds, the fused step, the prediction-only fallback -- as one compiled
C call (:mod:`estimators.online.compiled`, ``csrc/ss_ekf.c``; built once with gcc, cached on disk),
the same C that an exported controller runs (``mitigate export``); ``compile=False`` or a failed
build runs the Python reference of the same update on the CasADi Function.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from estimators.base import Estimate, EstimatorContext, StateEstimator
from estimators.online.model import EstimationModel, build_estimation_model
from estimators.online.observability import MIN_GAIN, ObservabilityReport, linearisation_function, observability
from estimators.online.compiled import CompiledEKF
from estimators.online.options import EKFOptions, for_rig
from models.errors import ConfigError, PluginError, SolverFailure
from models.status import Status

__all__ = ["EKF", "ekf_step_function", "ObservabilityMixin"]


def ekf_step_function(em: EstimationModel) -> ca.Function:
    """The fused predict + correct step ``(x, P, uh, y, m, p, q, r) -> (x_next, P_next)`` (SX)."""
    nx, ny, nc = em.nx, em.ny, len(em.channels)
    x = ca.SX.sym("x", nx)
    Pv = ca.SX.sym("P", nx * nx)
    uh = ca.SX.sym("uh", em.nuh)
    y = ca.SX.sym("y", nc)
    m = ca.SX.sym("m", nc)
    p = ca.SX.sym("p", len(em.p))
    q = ca.SX.sym("q", nx)
    r = ca.SX.sym("r", ny)
    P = ca.reshape(Pv, nx, nx)
    if em.FA is None:
        xp = em.F(x, uh, p)
        A = ca.jacobian(xp, x)
    else:
        xp, A = ca.SX.sym("xp", nx), ca.SX.sym("A", nx, nx)
    P = ca.mtimes([A, P, A.T]) + ca.diag(q + em.stick(x, uh, p))
    yi, mi = em.to_internal(y, m)
    xs = ca.SX.sym("xs", nx)
    hs = em.h(xs, uh, p)
    hC = ca.Function("hC", [xs, uh, p], [hs, ca.jacobian(hs, xs)])
    hx, C = hC(xp, uh, p)
    xc = xp
    for j in range(ny):
        cj = C[j, :]
        innov = yi[j] - (hx[j] + ca.mtimes(cj, xc - xp))
        Ph = ca.mtimes(P, cj.T)
        s = ca.mtimes(cj, Ph) + r[j]
        k = mi[j] * Ph / s
        xc = xc + k * innov
        P = P - ca.mtimes(k, Ph.T)
    if em.project is not None:
        xc = em.project(xc, uh, p)
    P = 0.5 * (P + P.T)
    names = ["x", "P", "uh", "y", "m", "p", "q", "r"]
    if em.FA is None:
        return ca.Function(f"{em.model.cname}_ekf_step", [x, Pv, uh, y, m, p, q, r], [xc, ca.reshape(P, nx * nx, 1)],
                           names, ["x_next", "P_next"])
    # the prediction as a loop over the substeps (em.FA), the rest as one expression
    rest = ca.Function(f"{em.model.cname}_ekf_update", [x, Pv, uh, y, m, p, q, r, xp, A],
                       [xc, ca.reshape(P, nx * nx, 1)])
    args = [ca.MX.sym(n, *a.shape) for n, a in zip(names, (x, Pv, uh, y, m, p, q, r))]
    xpM, AM = em.FA(args[0], args[2], args[5])
    return ca.Function(f"{em.model.cname}_ekf_step", args, list(rest(*args, xpM, AM)), names, ["x_next", "P_next"])


class ObservabilityMixin:
    """The observability checks the EKF and the MHE share (needs ``em``, ``options``, ``context``).

    At construction (``check_observability``) the estimator's own model is checked twice at
    the rig's operating-point input (:func:`models.modal.operating_point`):

    - ``observability``: along ``observability_window`` seconds simulated from the
      estimator's prior mean (for rig3 from rest: the start-up, break-away and stick-slip),
      i.e. what the configuration can know when the friction varies;
    - ``observability_steady``: at steady sliding, where nothing but the noise varies (the
      regime a successful mitigation creates).

    If the twist is not observable even along the first, every estimate carries
    ``Status.WARNING`` and the report's message.  Online, an estimate whose twist standard
    deviation exceeds ``p0_twist / MIN_GAIN`` says so too (the covariance is the filter's
    running observability measure: along an unobservable direction it grows with the
    random walks).
    """

    em: EstimationModel
    observability: ObservabilityReport | None = None
    observability_steady: ObservabilityReport | None = None

    def _check_observability(self) -> None:
        self.observability = None
        self.observability_steady = None
        self._lin = None
        self._tw_idx = np.array([self.em.names.index(t) for t in self.em.twist_names], int)
        self._tw_limit = (self.options.p0_twist / MIN_GAIN) ** 2
        if not self.options.check_observability:
            return
        from models.modal import operating_point

        em = self.em
        x_op = None
        try:
            u, x_op = operating_point(em.model, em.params)
        except Exception:   # a rig without a solvable operating point: check at zero input
            u = np.zeros(em.nu)
        uh = np.tile(u, em.delay + 1)
        n = max(int(round(self.options.observability_window / em.dt)), 2)
        X = np.empty((n, em.nx))
        X[0] = em.x0
        # one call for the whole start-up (the same steps as a loop of F's calls, without their
        # per-call conversions: 5000 samples of a 0.05 ms rig took 1.5 s that way)
        X[1:] = np.array(em.F.mapaccum(n - 1)(em.x0, np.tile(uh[:, None], (1, n - 1)),
                                              np.tile(np.asarray(em.p, float)[:, None], (1, n - 1)))).T
        if not np.all(np.isfinite(X)):
            raise ConfigError(f"{self.context.where}: the estimator's model diverges at the operating point "
                              f"{dict(zip(em.model.inputs, u))}; cannot check observability "
                              f"(check_observability = false skips it)")
        self.observability = self.observability_along(X, np.tile(uh, (n, 1)), full=True,
                                                      regime="start-up at the operating point")
        try:
            if x_op is None:
                x_op = em.model.steady_sliding(u, em.params)
            xs = em.full_state(x_op)
            if np.all(np.isfinite(xs)) and np.max(np.abs(np.array(em.F(xs, uh, em.p)).ravel() - xs)) < 1e-6:
                m = max(n // 2, 2)
                self.observability_steady = self.observability_along(np.tile(xs, (m, 1)), np.tile(uh, (m, 1)),
                                                                     full=True, regime="steady sliding")
        except Exception:   # no steady sliding at that input (a torque drive, a stall): nothing to say
            self.observability_steady = None

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(self.em.units)

    @property
    def observability_message(self) -> str:
        """One line: the verdicts of both construction-time checks."""
        parts = [r.message for r in (self.observability, self.observability_steady) if r is not None]
        return "; ".join(parts) if parts else "observability not checked"

    def observability_along(self, x, u, *, full: bool = False, regime: str = "the given trajectory",
                            min_gain: float = MIN_GAIN) -> ObservabilityReport:
        """Observability along a trajectory, e.g. the estimates of a logged run.

        Parameters
        ----------
        x : (N, nx) estimator states (``self.names``), or (N, nx_rig) rig states (augmented
            states at their prior values)
        u : (N, nu) inputs (``u[k]`` over the sample that ended at k), or with ``full=True``
            (N, nuh) input histories
        regime : words for the message
        min_gain : threshold of a weak direction (:mod:`estimators.online.observability`)
        """
        em = self.em
        x = np.asarray(x, float)
        u = np.asarray(u, float)
        if x.ndim == 2 and x.shape[1] == em.n_rig and em.n_rig != em.nx:
            x = np.array([em.full_state(r) for r in x])
        if not full and u.ndim == 2 and u.shape[1] == em.nu and em.delay:
            u = np.hstack([np.vstack([np.repeat(u[:1], d, axis=0), u[:len(u) - d]]) for d in range(em.delay + 1)])
        if self._lin is None:
            self._lin = linearisation_function(em)
        return observability(em, x, u, lin=self._lin, regime=regime, min_gain=min_gain)

    def observability_windows(self, x, u, *, window: float | None = None,
                              max_windows: int = 12) -> list[ObservabilityReport]:
        """:meth:`observability_along` on consecutive windows of a run (at most ``max_windows``,
        spread evenly), e.g. to see where along a log the twist was observable.

        Parameters
        ----------
        x : (N, nx) estimates, row k at sample k (row 0 the prior)
        u : (N, nu) inputs, row k the input over the sample that ended at k
        window : window length [s] (default: ``observability_window``)
        """
        x = np.asarray(x, float)
        u = np.asarray(u, float)
        n = x.shape[0] - 1
        w = min(int(round((window or self.options.observability_window) / self.em.dt)), n)
        if w < 2:
            return []
        starts = np.unique(np.linspace(1, n - w + 1, min(max_windows, max(n // w, 1))).astype(int))
        dt = self.em.dt
        return [self.observability_along(x[s:s + w], u[s:s + w], regime=f"t = {s * dt:.1f}-{(s + w) * dt:.1f} s")
                for s in starts]

    def _status(self, mask, P) -> tuple[Status, str]:
        """Status and message of an estimate: missing channels, and what it cannot know."""
        msg = "ok" if mask.all() else "missing " + ",".join(np.asarray(self.channels)[~mask])
        warn = []
        rep = self.observability
        if rep is not None and not rep.twist_observable:
            warn.append(rep.message)
        var = np.asarray(P).diagonal()[self._tw_idx]
        if (var > self._tw_limit).any():
            j = int(np.argmax(var))
            warn.append(f"twist uncertain: {self.em.twist_names[j]} std {np.sqrt(var[j]):.2g} rad")
        if warn:
            return Status.WARNING, "; ".join([msg] + warn)
        return Status.OK, msg


class EKF(ObservabilityMixin, StateEstimator):
    """Extended Kalman filter (module docstring).

    Parameters
    ----------
    options : :class:`estimators.online.options.EKFOptions`
    context : :class:`estimators.base.EstimatorContext` (rig, parameters, dt, sensors, x0)

    Attributes
    ----------
    em : the estimation model; names : estimator states; channels : measured channels
    observability : the construction-time :class:`ObservabilityReport` (None if not checked)
    compiled, compile_status : whether the fused step runs as compiled C
    """

    kind = "ekf"
    options_class = EKFOptions
    model_based = True

    def __init__(self, options: EKFOptions, context: EstimatorContext):
        options = for_rig(options, context.model, context.params)      # unit-carrying defaults from the rig
        super().__init__(options, context)
        self.em = build_estimation_model(context.model, context.params, options, context.dt, context.sensors,
                                         context.x0, context.where)
        em = self.em
        self.names = em.names
        self.channels = em.channels
        self.dt = em.dt
        self.step_fn = ekf_step_function(em)
        self.x = em.x0.copy()
        self.P = em.P0.copy()
        self.x0_used = self.x.copy()     # the prior mean of the first update
        self._uh = None
        self.compiled = False
        self.compile_status = "not requested"
        self._c = None
        if options.compile:
            try:
                self._c = CompiledEKF(self)
                self.compiled = True
                self.compile_status = f"compiled ({self._c.library.name})"
            except Exception as exc:   # fall back to the CasADi call, never fail here
                self.compile_status = f"compile failed, using CasADi: {exc}"
        self._check_observability()

    def _push_input(self, u: np.ndarray) -> np.ndarray:
        nu = self.em.nu
        if u.shape != (nu,):
            raise ConfigError(f"{self.context.where}: u must have {nu} entries {self.em.model.inputs}, got {u.shape}")
        if self._uh is None:
            self._uh = np.tile(u, self.em.delay + 1)
        elif self.em.delay:
            self._uh[nu:] = self._uh[:-nu].copy()
            self._uh[:nu] = u
        else:
            self._uh[:] = u
        return self._uh

    def _initial_speeds(self, y, mask) -> None:
        """Without an initial guess (``context.x0`` None), the first sample's measured speeds
        replace the at-rest prior's zeros: a filter started at rest on a rig in motion
        linearises the motor's friction tanh (and the regularised pin friction) at its steepest,
        and its first correction can throw the twist off by radians."""
        em = self.em
        for j, c in enumerate(self.channels):
            body = em.model.channel_body(c)
            s = em.model.sensor_of(c)
            if not mask[j] or body not in em.model.bodies or c != s.channels[-1] or s.offset is not None:
                continue
            name = f"omega_{body}"
            for n in [name] + [f"lag{d}:{name}" for d in range(1, em.delay + 1)]:
                self.x[em.names.index(n)] = y[j]

    def _delayed_zeros(self, u) -> None:
        """With delayed encoders, the zeroed reading of the first sample shows the angles
        ``delay`` samples earlier: the ``zero:`` states' prior is the twist then (one backward
        Euler step of the twist rates, which are the body speeds' differences)."""
        em = self.em
        zeros = [(j, n.partition(":")[2]) for j, n in enumerate(em.names) if n.startswith("zero:")]
        if not em.delay or not zeros:
            return
        rate = np.array(em.model.ode(self.options.eps)(self.x[:em.n_rig], u, em.p)).ravel()
        for j, tw in zeros:
            i = em.model.states.index(tw)
            self.x[j] = self.x[i] - em.delay * em.dt * rate[i]

    def _update_impl(self, t, y, mask, u):
        if self._c is not None:
            return self._update_compiled(t, y, mask, u)
        if self._uh is None:
            if self.context.x0 is None:
                self._initial_speeds(y, mask)
            self._delayed_zeros(u)
            self.x0_used = self.x.copy()
        uh = self._push_input(u)
        try:
            x, P = self._filter(uh, y, mask)
        except (SolverFailure, PluginError):
            raise
        except (RuntimeError, FloatingPointError, np.linalg.LinAlgError) as exc:   # CasADi's or the C step's
            raise SolverFailure(f"{type(exc).__name__}: {exc}") from exc
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise SolverFailure("non-finite estimate")     # the documented fallback: prediction only
        self.x, self.P = x, P
        status, msg = self._status(mask, P)
        return Estimate(t, x, P, self.names, status, msg, bool(mask.any()))

    def _filter(self, uh, y, mask):
        """One predict + correct step: ``(x, P)`` (the Python reference: the CasADi Function)."""
        nx = self.em.nx
        xo, Po = self.step_fn(self.x, self.P.ravel(order="F"), uh, np.where(mask, y, 0.0), mask.astype(float),
                              self.em.p, self.em.q, self.em.r)
        return np.array(xo).ravel(), np.array(Po).reshape(nx, nx, order="F")

    def _update_compiled(self, t, y, mask, u):
        """The same update as one compiled C call (``csrc/ss_ekf.c``); a failed update raises
        SolverFailure and :meth:`_fallback` returns the C core's prediction-only estimate."""
        first = self._uh is None
        self._push_input(u)
        c = self._c
        info = c.update(y, u)          # y is NaN where missing (StateEstimator.update); the core skips non-finite
        if first:
            self.x0_used = c.x0_used
        self.x, self.P = c.x, c.P
        if info.failed:
            self._c_fallback = info.held == 0
            raise SolverFailure("non-finite estimate")
        status, msg = self._status(mask, self.P)
        return Estimate(t, self.x, self.P, self.names, status, msg, bool(mask.any()))

    def prior(self) -> Estimate:
        """The prior mean and covariance, before the first sample (``t`` NaN, not corrected)."""
        return Estimate(float("nan"), self.x.copy(), self.P.copy(), self.names, Status.OK, "prior", False)

    def reset(self, x, P=None) -> None:
        """Restart from the estimator state ``x`` and covariance ``P`` (the prior's if None)."""
        x = np.asarray(x, float).ravel()
        if x.shape != (self.em.nx,):
            raise ConfigError(f"{self.context.where}: reset x must have {self.em.nx} entries {self.names}")
        self.x = x.copy()
        self.P = self.em.P0.copy() if P is None else np.asarray(P, float).copy()
        if self._c is not None:
            self._c.set(self.x, self.P)

    def _fallback(self, t, y, mask, u, message):
        """Prediction by the CasADi Function (no correction); keeps the filter alive."""
        if self._c is not None and getattr(self, "_c_fallback", False):
            self._c_fallback = False
            return Estimate(t, self.x, self.P, self.names, Status.FALLBACK, f"{message} (prediction only)", False)
        try:
            uh = self._uh if self._uh is not None else np.tile(u, self.em.delay + 1)
            nc = len(self.channels)
            xo, Po = self.step_fn(self.x, self.P.ravel(order="F"), uh, np.zeros(nc), np.zeros(nc), self.em.p,
                                  self.em.q, self.em.r)
            x = np.array(xo).ravel()
            P = np.array(Po).reshape(self.em.nx, self.em.nx, order="F")
            if np.all(np.isfinite(x)) and np.all(np.isfinite(P)):
                self.x, self.P = x, P
                return Estimate(t, x, P, self.names, Status.FALLBACK, f"{message} (prediction only)", False)
        except Exception:
            pass
        return super()._fallback(t, y, mask, u, message)
