"""The identification problem: which parameters, which data, which equations.

:class:`IdentificationProblem` takes a rig (any rig file), one or several logs, an initial
parameter set and :class:`~estimators.identify.options.IdentifyOptions`, checks them, and
builds the multiple-shooting least-squares problem:

- **Model**: the rig's regularised model (:meth:`models.rig.RigModel.smooth_rhs`, tanh friction
  of width ``eps``), RK4 with ``nsub`` substeps per DAQ sample, the input held over the sample.
- **Inputs**: the model's inputs (``model.inputs``) read from the log columns of the same
  names (their quantity checked), low-passed where ``input_cutoff`` says, and corrected through
  the rig's load cells inside the model (:meth:`~models.rig.RigModel.input_from_measured`), so
  a load cell's ``<channel>_offset`` / ``_gain`` can be freed like any parameter.  Row convention
  ``input_row``: "end" (our plant: row k+1 holds the input over [t_k, t_k+1)) or "start".
- **Outputs**: the rig's sensor channels found in the log (:mod:`~estimators.identify.outputs`),
  each shifted back by its sensor delay, each weighted by its noise level
  (:mod:`~estimators.identify.noise`); encoder angle differences with a per-log encoder zero.
- **Decision variables**: the free parameters, the encoder zeros, the state at every
  ``shoot_every``-th sample of every log (continuity between consecutive intervals is a
  constraint), and with errors in the variables a correction per interval and noisy input.
- **Constraints**: the parameters' bounds, ``mu_k <= mu_s`` for every Stribeck-type contact
  whose two levels are free, and ``options.constraints``.

:meth:`IdentificationProblem.solve` returns a :class:`~estimators.identify.result.FitResult`
that keeps the problem; :meth:`IdentificationProblem.refit` solves a derived problem (other
logs, other options, a warm start) — the systematic refit, the delay detection and the
bootstrap replicates are such refits.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace

import numpy as np

from models.errors import ConfigError, SolverFailure
from models.params import ParameterSet
from models.rig import RigModel, get_model
from models.status import Status
from models.discretise import MAX_SUBSTEPS, integration
from models.sdirk import GAMMA
from estimators.identify.assemble import fit_result
from estimators.identify.continuation import (GN_METHOD, attempt, choose, closed, continuation_method,
                                              solve_continuation, wants_continuation)
from estimators.identify.data import align_logs, check_logs, check_option_names
from estimators.identify.functions import StiffRate, shooting_functions
from estimators.identify.gauss_newton import solve_gn
from estimators.identify.guess import initial_guess
from estimators.identify.ipopt import solve_ipopt
from estimators.identify.noise import detect_input_noise, input_noise_hints, output_noise
from estimators.identify.options import EPS_RIG3, IdentifyOptions, default_eps
from estimators.identify.outputs import input_delays, plan_channels
from estimators.identify.result import FitResult
from estimators.identify.shooting import ShootingProblem
from estimators.identify.single import refine
from estimators.identify.start import (constraint_rows, constraints, free_bounds, initial_nodes, scaled_constraints,
                                      state_scales)
from estimators.identify.systematic import systematic_error
from estimators.identify.validation import period_channel, validate
from models.signals import slip_events

__all__ = ["IdentificationProblem", "START_PERIODS"]

#: stick-slip periods of the first log a start (the guess or the rig file's values) is judged over
START_PERIODS = 2.5

_KEEP = object()
def _model_from(spec, key: str) -> RigModel:
    try:
        m = get_model(key)
        if m.spec == spec:
            return m
    except Exception:  # noqa: BLE001 - an in-memory rig: rebuild it from its spec
        pass
    return RigModel(spec, key)


def _rebuild(spec, key, logs, initial, options, holdout):
    return IdentificationProblem(_model_from(spec, key), logs, initial, options, holdout=holdout)


class IdentificationProblem:
    """A multiple-shooting identification problem (see the module docstring).

    Parameters
    ----------
    model : a rig name, rig-file path or :class:`models.rig.RigModel`
    logs : a :class:`models.logs.Log` or a sequence of them (one sample period)
    initial : the starting values and the fixed parameters; None: the rig's published set with
        the free parameters guessed from the data (:func:`~estimators.identify.guess.initial_guess`)
    options : :class:`~estimators.identify.options.IdentifyOptions`; the problem keeps them with the
        rig's defaults filled in (``problem.options.eps``: :func:`~estimators.identify.options.default_eps`
        when None; ``problem.eps_source`` says which)
    holdout : fraction in [0, 0.9) of the end of each log kept out of the fit; the first log's
        is predicted afterwards with the exact plant (:class:`~estimators.identify.validation.Validation`)

    Raises
    ------
    ConfigError : unknown parameter or channel, bad bounds or constraints, an initial value
        outside them
    DataError : a log lacks an input or output column, has another sample period, or is too short
    """

    def __init__(self, model, logs, initial: ParameterSet | None = None, options: IdentifyOptions | None = None, *,
                 holdout: float = 0.0):
        if not isinstance(options, IdentifyOptions):
            raise ConfigError(f"options must be IdentifyOptions (at least the free parameters), "
                              f"got {type(options).__name__}")
        m = get_model(model)
        #: where the friction regularisation came from ("given", or the rig's default and why)
        self.eps_source = "given"
        if options.eps is None:
            options = options.replace(eps=default_eps(m))
            self.eps_source = (f"default: rig3's {EPS_RIG3:g} rad/s at its 30 rpm carried to the nominal speed "
                               f"{m.nominal_speed():g} rad/s")
        self.model, self.options = m, options
        if isinstance(holdout, bool) or not (isinstance(holdout, (int, float)) and 0 <= holdout < 0.9):
            raise ConfigError(f"holdout must be a fraction in [0, 0.9), got {holdout!r}")
        self.holdout = float(holdout)
        o = options
        check_option_names(m, o)
        self.logs, self.dt = check_logs(m, logs, o)
        logs = self.logs
        # ---- initial set (data-derived guess if none)
        #: the initial set as given (None: guessed from the data)
        self.given_initial = initial
        self.guess_notes: tuple[str, ...] = ()
        self._alternative = None
        if initial is None:
            # from the training parts only: the held-out end must not steer the start of the fit it judges
            train = [lg if self.holdout == 0 else lg.slice(float(lg.t[0]), float(lg.t[int(round(len(lg.t) * (1 - self.holdout)))]))
                     for lg in logs]
            g = initial_guess(m, train, o.free, m.published(), encoder_zero=o.encoder_zero, input_row=o.input_row)
            initial = g.params
            self.guess_notes = g.notes
            if g.values:
                self._alternative = m.published()   # compared with the guess in shooting()
        else:
            m.check_params(initial, "initial")
        self.initial = initial
        self.free = o.free
        self.free_idx = [m.param_names.index(n) for n in o.free]
        self.theta0, self.lo, self.hi = free_bounds(m, initial, o, guessed=self.given_initial is None)
        self.constraints = constraints(m, o)
        Gp, hp = self.constraint_rows()
        if Gp.shape[0] and self.given_initial is None and np.any(Gp @ self.theta0 - hp > 1e-9 * np.maximum(1.0, np.abs(hp))):
            # the data-derived guess breaks a constraint: start from the rig file's values instead
            self.guess_notes = ("guess not used: it breaks a constraint; started from the rig file's values",)
            self.initial, self._alternative = m.published(), None
            self.theta0 = np.clip(self.initial.vector(o.free), self.lo, self.hi)
        if Gp.shape[0]:
            viol = Gp @ self.theta0 - hp
            j = int(np.argmax(viol))
            if viol[j] > 1e-9 * max(1.0, abs(hp[j])):
                c = self.constraints[j]
                vals = ", ".join(f"{n} = {self.theta0[o.free.index(n)]:g}" for n in c.names if n in o.free)
                if self.given_initial is None:
                    raise ConfigError(f"the rig file's {vals} and the data-derived guess violate the constraint {c.text}; "
                                      f"give a starting set that satisfies it (initial, CLI --params)")
                raise ConfigError(f"initial {vals} violates the constraint {c.text}")
        # ---- channels, delays, alignment
        self.channels = plan_channels(m, logs[0], o)
        self.input_delays = input_delays(m, o.extra_delay)
        self.data = align_logs(m, logs, self.channels, self.input_delays, o, self.holdout)
        self.noise, self.noise_source = {}, {}
        for c in self.channels:
            self.noise[c.name], self.noise_source[c.name] = output_noise(m, c, logs[0], o, self.dt)
        # ---- errors in the variables
        if o.input_noise == "auto":
            self.input_noise = {k: v for k, v in detect_input_noise(logs, m).items()
                                if k not in (o.input_cutoff or {})} if o.solver == "gn" else {}
        elif o.input_noise in ("off", None):
            self.input_noise = {}
        else:
            self.input_noise = dict(o.input_noise)
        self.hints = input_noise_hints(logs, m, o.input_cutoff, self.input_noise) if o.solver == "gn" else []
        # ---- substeps
        umax = np.max(np.abs(np.concatenate([d.U for d in self.data])), axis=0) if m.nu else np.zeros(0)
        self._umax = np.array(m.input_from_measured(list(umax), m.unpack(initial.vector())), float).ravel()
        #: how a sample is integrated (:func:`models.discretise.integration`; ``nsub`` a floor)
        self.integration = integration(m, initial, self.dt, u=self._umax, eps=o.eps, nsub=o.nsub,
                                       max_nsub=None if o.nsub is not None else MAX_SUBSTEPS,
                                       where="options.nsub" if o.nsub is not None else "identification",
                                       method=None if o.integrator == "auto" else o.integrator)
        self.nsub = self.integration.nsub
        self._stiff = None
        self._h_lambda0 = None
        self._sh = None
        #: what the start could not do (the start-up estimator's failure), reported with the fit
        self.start_notes: tuple[str, ...] = ()

    # ------------------------------------------------------------------ pickling, derived problems
    def __reduce__(self):
        return (_rebuild, (self.model.spec, self.model.key, self.logs, self.given_initial, self.options, self.holdout))

    def __repr__(self) -> str:
        return (f"IdentificationProblem({self.model.name!r}: {len(self.logs)} log(s), free {', '.join(self.free)}, "
                f"outputs {', '.join(c.name for c in self.channels)})")

    def derive(self, *, logs=None, initial=_KEEP, holdout: float | None = None, **changes) -> "IdentificationProblem":
        """The same problem with other logs, another initial set (None: guess from the data), another
        hold-out or other options (``changes`` are :class:`IdentifyOptions` fields)."""
        prob = IdentificationProblem(self.model, self.logs if logs is None else logs,
                                     self.given_initial if initial is _KEEP else initial,
                                     self.options.replace(**changes) if changes else self.options,
                                     holdout=self.holdout if holdout is None else holdout)
        if "eps" not in changes:
            prob.eps_source = self.eps_source
        return prob

    def refit(self, warm: FitResult | None = None, *, logs=None, initial=_KEEP, holdout: float | None = None,
              **changes) -> FitResult:
        """Solve :meth:`derive` ``(logs=..., initial=..., holdout=..., **changes)``, warm-started
        from ``warm`` (its parameters, and its node states and encoder zeros where they fit)."""
        return self.derive(logs=logs, initial=initial, holdout=holdout, **changes).solve(warm)

    # ------------------------------------------------------------------ constraints
    def constraint_rows(self):
        """``G theta <= h`` for the non-bound constraints (fixed parameters moved to the right-hand side)."""
        return constraint_rows(self.constraints, self.free, self.initial)

    # ------------------------------------------------------------------ the numerical problem
    def shooting(self) -> ShootingProblem:
        """The multiple-shooting problem (built once: compiled functions, start, scales)."""
        if self._sh is not None:
            return self._sh
        m, o = self.model, self.options
        M = o.shoot_every
        avg = [c.kind == "speed" for c in self.channels]
        eiv = self.input_noise
        use_c = o.compile if o.compile is not None else (o.solver == "gn")
        S_run, Sv_run, Sv, self.compiled = shooting_functions(m, self.integration, self.channels, avg, self.free_idx, bool(eiv), use_c)
        self._S_val = Sv
        #: one sample's values-only function (compiled where the fit is), for single shooting
        self.values_function = Sv_run
        Ub, Yb, starts, zmap = [], [], [], []
        node_off = 0
        nz = 0
        self.zero_index: list[dict] = []
        zidx_ch = [j for j, c in enumerate(self.channels) if c.zero]
        for d in self.data:
            rows = slice(1, d.nint * M + 1)
            Uint = d.U[1:d.nint * M + 1] if o.input_row == "end" else d.U[:d.nint * M]
            Ub.append(Uint.reshape(d.nint, M, m.nu))
            Yb.append(d.Y[rows].reshape(d.nint, M, len(self.channels)))
            starts.append(node_off + np.arange(d.nint))
            node_off += d.nint + 1
            zm = np.full((d.nint, len(self.channels)), -1, int)
            zi = {}
            for j in zidx_ch:
                zm[:, j] = nz
                zi[self.channels[j].name] = nz
                nz += 1
            zmap.append(zm)
            self.zero_index.append(zi)
        U, Y = np.concatenate(Ub), np.concatenate(Yb)
        sig = np.array([self.noise[c.name] for c in self.channels])
        if self._alternative is not None:
            self._choose_start(Sv_run, U, Y, sig, np.concatenate(starts), np.concatenate(zmap), nz)
        init_nodes, z0, self.start_notes = self._initial_nodes(Sv_run)
        self.x_scale = state_scales(m, self.channels, init_nodes)
        th0 = self.theta0
        ths = np.where(np.abs(th0) > 0, np.abs(th0), np.maximum(self.hi - self.lo, 1e-6) * 0.1)
        self.th_scale = np.where(np.isfinite(ths), ths, 1.0)
        zs = np.ones(nz)
        for d, zi in zip(self.data, self.zero_index):
            for name, j in zi.items():
                col = [c.name for c in self.channels].index(name)
                zs[j] = max(abs(z0[j]), float(np.ptp(d.Y[:, col])), 1e-3)
        self._init_nodes, self._z0 = init_nodes, z0
        self._sh = ShootingProblem(S_run, m.nx, m.n_p, self.initial.vector(), self.free_idx, self.th_scale,
                                   self.x_scale, U, Y, 1.0 / sig, np.concatenate(starts), self.dt, o.eps,
                                   zmap=np.concatenate(zmap), z_scale=zs, S_val=Sv_run,
                                   eiv_idx=[m.inputs.index(n) for n in eiv],
                                   eiv_scale=[eiv[n] / math.sqrt(M) for n in eiv])
        return self._sh

    def _start_window(self) -> tuple[int | None, str]:
        """``(intervals, what)``: the first log's shooting intervals a start is judged over -- its training
        part's first :data:`START_PERIODS` stick-slip periods where slips are found in it
        (:func:`models.signals.slip_events` on the period channel, as the hold-out reads them); None where
        there are none: then every interval one step ahead from its own data-initialised node."""
        d, M = self.data[0], self.options.shoot_every
        ch, kind = period_channel(self.model, self.channels)
        j = [c.name for c in self.channels].index(ch)
        y = d.Y[:d.nint * M + 1, j]
        ev = slip_events(y, self.dt, kind, noise=self.noise.get(ch) or None)
        if not np.isfinite(ev.period):
            return None, "one shooting interval from each node"
        n = int(min(d.nint, max(1, math.ceil(START_PERIODS * ev.period / (self.dt * M)))))
        return n, f"its first {n * M * self.dt:.3g} s ({START_PERIODS:g} stick-slip periods of {ev.period:.3g} s)"

    def _start_cost(self, Sv, U, Y, sig, starts, zmap, nz, n_int) -> float:
        """``0.5 |r|^2`` of the current initial set's simulation of the first log's first ``n_int`` shooting
        intervals from its first data-initialised node (through the logged inputs): how well it predicts
        the log.  ``n_int`` None: every log's every interval from its own node (one interval ahead)."""
        from estimators.identify.single import SimulationError
        m = self.model
        nodes, z0, _ = self._initial_nodes(Sv)
        if n_int is None:
            sh = ShootingProblem(Sv, m.nx, m.n_p, self.initial.vector(), self.free_idx, np.ones(len(self.free)),
                                 np.ones(m.nx), U, Y, 1.0 / sig, starts, self.dt, self.options.eps, zmap=zmap,
                                 z_scale=np.ones(nz), S_val=Sv)
            r = sh.evaluate(np.concatenate([self.theta0, z0] + [n.ravel() for n in nodes]), jac=False)[0]
            return 0.5 * float(r @ r) if np.all(np.isfinite(r)) else float("inf")
        sh = ShootingProblem(Sv, m.nx, m.n_p, self.initial.vector(), self.free_idx, np.ones(len(self.free)),
                             np.ones(m.nx), U[:n_int], Y[:n_int], 1.0 / sig, np.arange(n_int), self.dt,
                             self.options.eps, zmap=zmap[:n_int], z_scale=np.ones(nz), S_val=Sv)
        ss = SimulationError(sh, Sv, [n_int])
        w = np.concatenate([self.theta0, z0, nodes[0][:n_int + 1].ravel()])
        r = ss.evaluate(ss.start(w), jac=False)[0]
        return 0.5 * float(r @ r) if np.all(np.isfinite(r)) else float("inf")

    def _choose_start(self, Sv, U, Y, sig, starts, zmap, nz) -> None:
        """Start from the data-derived guess or from the rig file's values, whichever simulates the first
        log better over :meth:`_start_window` (one shooting interval from measured nodes said nothing
        of a 1.7 s stick-slip cycle: on the 168 N/m paper slider it chose the rig file's values, whose
        stick would last 8.5 s)."""
        n_int, what = self._start_window()
        guess, theta_g = self.initial, self.theta0.copy()
        c_guess = self._start_cost(Sv, U, Y, sig, starts, zmap, nz, n_int)
        alt = self._alternative
        theta_a = np.clip(alt.vector(self.free), self.lo, self.hi)
        Gp, hp = self.constraint_rows()
        self.initial, self.theta0 = alt, theta_a
        c_alt = self._start_cost(Sv, U, Y, sig, starts, zmap, nz, n_int) \
            if not Gp.shape[0] or np.all(Gp @ theta_a <= hp + 1e-12) else float("inf")
        if c_guess <= c_alt:
            self.initial, self.theta0 = guess, theta_g
            self.guess_notes = self.guess_notes + (f"started from the guess: simulating the log over {what} it "
                                                   f"costs {c_guess:.4g}, the rig file's values {c_alt:.4g}",)
        else:
            self.guess_notes = (f"started from the rig file's values: simulating the log over {what} they cost "
                                f"{c_alt:.4g}, the data-derived guess {c_guess:.4g} "
                                f"(guess not used: " + "; ".join(self.guess_notes) + ")",)
        self._alternative = None

    def _initial_nodes(self, S_val):
        """:func:`~estimators.identify.start.initial_nodes` of this problem."""
        return initial_nodes(self.model, self.channels, self.data, self.initial, self.theta0, self.options, self.dt,
                             S_val)

    def decision_vector(self, warm: FitResult | None) -> np.ndarray:
        """The scaled decision vector of the shooting problem at the start (``warm``: None), or at
        ``warm``'s parameters, node states, encoder zeros and input corrections where they fit."""
        sh = self.shooting()
        theta = self.theta0.copy()
        nodes = [n.copy() for n in self._init_nodes]
        z = self._z0.copy()
        if warm is not None:
            if tuple(warm.names) == tuple(self.free):
                theta = np.clip(np.asarray(warm.estimate, float), self.lo, self.hi)
            if [len(s) for s in warm.states] == [d.nint + 1 for d in self.data]:
                nodes = [np.asarray(s, float).copy() for s in warm.states]
            zw = [z_ for zl in warm.encoder_zero for z_ in zl.values()]
            if len(zw) == z.size:
                z = np.asarray(zw, float)
        deltas = np.zeros((sh.Nint, sh.ne))
        if warm is not None and warm.input_corrections and sh.ne:
            dw = np.concatenate(warm.input_corrections) if len(warm.input_corrections) else np.zeros((0, sh.ne))
            if dw.shape == deltas.shape and tuple(warm.input_noise) == tuple(self.input_noise):
                deltas = dw
        w0 = np.concatenate([theta / sh.th_scale, z / sh.z_scale]
                            + [(n / sh.x_scale).ravel() for n in nodes]
                            + [(deltas / sh.d_scale if sh.ne else deltas).ravel()])
        return w0

    def scaled_constraints(self):
        """All inequalities, bounds included, on the scaled border variables: ``G w[:nb] <= h``."""
        return scaled_constraints(self.shooting(), self.free, self.lo, self.hi, self.constraints,
                                  *self.constraint_rows())

    # ------------------------------------------------------------------ solving
    def solve(self, warm: FitResult | None = None) -> FitResult:
        """Fit (see the module docstring): the delay search if ``detect_delay``, the systematic refit
        if ``systematic``, the hold-out validation if ``holdout``.

        Raises
        ------
        SolverFailure : the solver returned non-finite values.
        """
        if self.options.detect_delay and warm is None:
            return self._detect_delay()
        fit = self.fit_once(warm)
        # (a fit whose gaps stayed open has parameters of no trajectory: no substeps are raised for them;
        # the slider's stalled fit, v_s at its bound, asked for many more and its refit took minutes)
        if self.options.nsub is None and np.all(np.isfinite(fit.estimate)) and closed(fit):
            # the fitted parameters may be stiffer than the initial ones: refit (warm) with the
            # substeps they need, at most twice
            prob, first = self, fit
            for _ in range(2):
                # refit only where RK4 leaves the range the fits were measured unchanged in
                # (h |lambda| <= 3.5) by more than a margin (4.0): a 9 -> 10 substep refit of every
                # rig3 fit doubled its time for nothing; the implicit step: where the fitted friction
                # falls faster with speed than its substeps resolve
                implicit = prob.integration.implicit
                if not implicit and self.stiff_rate(fit.estimate) * self.dt / prob.nsub <= \
                        max(4.0, 1.25 * (self._h_lambda0 or 0.0)):
                    break
                need = integration(self.model, fit.params, self.dt, u=self._umax, eps=self.options.eps,
                                   where="identification", method=prob.integration.method if implicit else None).nsub
                if need <= prob.nsub:
                    break
                old = prob.nsub
                prob = prob.derive(nsub=need, integrator=prob.integration.method)
                fit = prob.fit_once(fit)
                fit = replace(fit, initial=first.initial, guess_notes=first.guess_notes,
                              warnings=fit.warnings + (f"substeps raised from {old} to {need} for the fitted "
                                                       f"parameters (stiffer than the initial ones) and refitted",))
            return prob._finish(prob._globalise(fit, warm))
        return self._finish(self._globalise(fit, warm))

    def stiff_rate(self, theta) -> float:
        """The model's stiffest rate [1/s] with the free parameters at ``theta`` (largest logged inputs)."""
        return self._stiff_rate()(self._p_of(theta))

    def _stiff_rate(self) -> StiffRate:
        if self._stiff is None:
            self._stiff = StiffRate(self.model, self.initial, self._umax, self.options.eps,
                                    self.integration.quasi_static)
        return self._stiff

    def rk4_stable(self, w) -> bool:
        """RK4 with ``nsub`` substeps stays usable for the trial parameters: ``h |lambda|max`` at the
        stiffest point at most 4.5 (the substeps are chosen for 3.5; a disc fit blew up at 5.5, its
        Jacobians reaching 1e16), or 1.25 times its value at the start where that is already higher
        (the lead screw's regularised law has a positive 1e7 1/s eigenvalue right at zero speed,
        which the fit crosses in no time)."""
        theta = np.asarray(w[:len(self.free)], float) * self.shooting().th_scale
        if self.integration.implicit:
            # the implicit step damps any stable rate; it must resolve a friction that falls with speed
            # (a positive rate: one root per stage), with the same margin as RK4's 3.5 -> 4.5
            return self._stiff_rate().growth(self._p_of(theta)) * GAMMA * self.dt / self.nsub <= 1.0
        if self._h_lambda0 is None:
            self._h_lambda0 = self.stiff_rate(self.theta0) * self.dt / self.nsub
        return self.stiff_rate(theta) * self.dt / self.nsub <= max(4.5, 1.25 * self._h_lambda0)

    def _p_of(self, theta):
        p = self.initial.vector()
        p[self.free_idx] = theta
        return p

    def _finish(self, fit: FitResult) -> FitResult:
        if self.options.systematic and fit.status is not Status.FAILED:
            fit = systematic_error(self, fit)
        if self.holdout > 0 and fit.status is not Status.FAILED:
            fit = replace(fit, validation=validate(self, fit))
        return fit

    def _detect_delay(self) -> FitResult:
        o = self.options
        fits, probs, costs = {}, {}, {}
        for dly in range(o.detect_delay + 1):
            p = self.derive(extra_delay=o.extra_delay + dly, detect_delay=0, systematic=False)
            f = p.fit_once(None)
            probs[dly], fits[dly] = p, f
            n_out = sum(d.nint * o.shoot_every for d in p.data) * len(p.channels)
            costs[dly] = 2 * f.cost / max(n_out, 1)
        best = min(costs, key=costs.get)
        fit = probs[best]._globalise(fits[best], None)
        note = (f"DAQ delay: an extra delay of {best} sample(s) fits best (cost per residual "
                + ", ".join(f"{d}: {c:.4g}" for d, c in costs.items()) + ")")
        fit = replace(fit, delay=o.extra_delay + best, delay_costs=costs, message=f"{fit.message}; {note}")
        return probs[best]._finish(fit)

    def _globalise(self, fit: FitResult, warm: FitResult | None) -> FitResult:
        """``fit`` (direct), or the better of it and a cold refit along a continuation in eps
        (:mod:`~estimators.identify.continuation`); made consistent (:meth:`consistent`)."""
        o = self.options
        why = wants_continuation(fit, o.globalise if o.solver == "gn" else "off", warm is not None)
        if why is None:
            return self.consistent(fit)
        return choose(fit, self.fit_once(None, continuation=True), why, self.consistent)

    def consistent(self, fit: FitResult) -> FitResult:
        """``fit``, or where its solver stopped with the continuity gaps open (its parameters belong to no
        trajectory of the model) its continuation by single shooting (:func:`~estimators.identify.single.refine`)."""
        if closed(fit) or fit.status is Status.FAILED or fit.reason == "max_iter":
            return fit              # (a fit cut short by its iteration limit stays not converged: the budget is the user's)
        refined = refine(self, fit, fit.message.split(". Try:")[0])
        return fit if refined is None else refined

    def fit_once(self, warm: FitResult | None, continuation: bool = False) -> FitResult:
        """One solve (no delay search, no substep raise, no systematic refit): the direct fit, or with
        ``continuation`` the cold continuation in eps, warm-started from ``warm``."""
        t_start = time.perf_counter()
        m, o = self.model, self.options
        sh = self.shooting()
        w0 = self.decision_vector(warm)
        G, h, _ = self.scaled_constraints()
        label = f"identify {m.name}"

        def _progress(it, f, gmax, step):
            sys.stderr.write(f"\r{label}: iteration {it:3d}, cost {f:.6g}, gap {gmax:.2e}, step {step:.2e}   ")
            sys.stderr.flush()

        if o.solver == "gn":
            gn = dict(max_iter=o.max_iter, tol=o.tol, trust_radius=o.trust_radius,
                      callback=_progress if o.progress else None, admissible=self.rk4_stable)
            if continuation:
                res, _ = solve_continuation(sh, w0, G, h, o.eps, **gn)
                method = continuation_method(o.eps)
            else:
                res, method = solve_gn(sh, w0, G, h, **gn), GN_METHOD
        else:
            res = solve_ipopt(sh, self._S_val, w0, G, h, max_iter=o.max_iter, tol=o.tol, progress=o.progress,
                              label=label)
            method = "IPOPT (Gauss-Newton Hessian, MUMPS)"
        if o.progress and o.solver == "gn":
            sys.stderr.write("\n")
        if not np.all(np.isfinite(res.w)):
            raise SolverFailure(f"identify {m.name}: the solver returned non-finite values ({res.reason})")
        nf = len(self.free)
        return fit_result(self, sh, res.w, res, method=method, attempts=(attempt(method, res, t_start),),
                          initial=self.theta0 if warm is None else w0[:nf] * sh.th_scale, t_start=t_start)
