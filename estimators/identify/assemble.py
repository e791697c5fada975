"""A solver's end made into a :class:`~estimators.identify.result.FitResult`.

:func:`fit_result` takes the scaled solution of an identification problem's shooting problem
(multiple shooting, or the trajectory of a single-shooting refinement: nodes on one simulation)
and derives everything a result states from it: the parameters moved onto their constraints,
standard errors and conditioning (:mod:`~estimators.identify.covariance`), the identifiability
warnings, the trajectories and residuals per log, what the structure misses
(:mod:`~estimators.identify.diagnostics`) and the status with its message
(:func:`~estimators.identify.result.fit_status`).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from estimators.identify.covariance import uncertainty
from estimators.identify.data import nrmse, split_by_log
from estimators.identify.diagnostics import diagnose, gap_locator
from estimators.identify.result import (FitResult, IdentifiabilityWarning, convergence_message, fit_status,
                                        identifiability_warnings, level_twist_warning)
from estimators.identify.start import feasible
from models.sensors import channel_std

__all__ = ["fit_result"]


def fit_result(problem, sh, w, res, *, method: str, attempts: tuple, initial, t_start: float,
               refined: str = "") -> FitResult:
    """The :class:`FitResult` of ``problem`` at the scaled solution ``w`` of its shooting problem ``sh``.

    Parameters
    ----------
    problem : the :class:`~estimators.identify.problem.IdentificationProblem`
    sh : its :class:`~estimators.identify.shooting.ShootingProblem`
    w : (nw,) scaled decision vector (parameters, encoder zeros, nodes, input corrections)
    res : the solver's result (``reason``, ``success``, ``iterations``, ``max_gap``, ``costs``, ``history``)
    method : how it was solved; attempts : every solve, in order
    initial : (n_free,) the starting values [SI]
    t_start : ``time.perf_counter()`` when the solve began
    refined : "" for a multiple-shooting end; else why a single-shooting refinement followed and
        how the multiple-shooting fit had ended (the result is then the refinement's, on one
        consistent trajectory, and its status says so)
    """
    m, o = problem.model, problem.options
    r, g, Jr, A, Ypred = sh.evaluate(w)
    theta, z, nodes = sh.split(w)
    theta = feasible(theta, problem.lo, problem.hi, *problem.constraint_rows())
    free = problem.free
    twists = [(j, c) for j, c in enumerate(problem.channels) if c.kind == "twist" and not c.zero]
    offs = [(j, problem.noise[c.name]) for j, c in twists]
    unc = uncertainty(sh, w, r, Jr, A, free, rse_warn=o.rse_warn, offsets=offs,
                      offset_phases=offset_phases(problem.model, [c for _, c in twists], problem.dt, o.sensors))
    se, corr = unc.stderr, unc.corr
    tol_b = 1e-6 * sh.th_scale
    lo, hi = problem.lo, problem.hi
    at_bound = tuple(n for i, n in enumerate(free) if (theta[i] - lo[i]) <= tol_b[i] or (hi[i] - theta[i]) <= tol_b[i])
    G, h, labels = problem.scaled_constraints()
    slack = h - G @ w[:sh.nb] if G.shape[0] else np.zeros(0)
    active = tuple(lab[1] for lab, s, hh in zip(labels, slack, h)
                   if lab[0] == "constraint" and s <= 1e-8 * max(1.0, abs(float(hh))))
    # ---- warnings
    zero_names = [""] * sh.nz
    for li, zi in enumerate(problem.zero_index):
        for ch, j in zi.items():
            zero_names[j] = ch + (f" (log {li + 1})" if len(problem.zero_index) > 1 else "")
    torque = any(c.kind != "twist" and getattr(m.sensor_of(c.name), "kind", None) == "torque"
                 for c in problem.channels)
    warns = list(problem.hints) + list(problem.start_notes) \
        + identifiability_warnings(free, theta, se, corr, unc, at_bound, active, o, zero_names, torque=torque) \
        + level_twist_warning(m, free, problem.channels)
    for msg in warns:
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=4)
    costs = getattr(res, "costs", ())
    message = convergence_message(res.reason, res.success, iterations=res.iterations, max_iter=o.max_iter,
                                  costs=costs, at_bound=at_bound, max_gap=res.max_gap, condition=unc.condition,
                                  weak=unc.weak, solver=o.solver, shoot_every=o.shoot_every, eps=o.eps,
                                  n_free=len(free))
    # ---- fitted set and trajectories
    fitted = problem.initial.with_vector(free, theta).with_meta(
        stderr=tuple((n, float(s)) for n, s in zip(free, se) if np.isfinite(s)))
    dlt = sh.deltas(w) if sh.ne else np.zeros((sh.Nint, 0))
    M = o.shoot_every
    names = [c.name for c in problem.channels]
    sig = np.array([problem.noise[c] for c in names])
    Yp = Ypred.reshape(-1, len(names))
    Ym = sh.Ymeas.reshape(-1, len(names))
    t_l, meas_l, sim_l, res_l, states, zeros, corr_l = split_by_log(problem.data, problem.zero_index, M, names, sig,
                                                                    Ym, Yp, nodes, z, dlt)
    structure = diagnose(res_l, meas_l, problem.dt, sigma2=unc.sigma2, gaps=g,
                         gap_locator=gap_locator([d.nint for d in problem.data], [d.t for d in problem.data], M,
                                                 m.states))
    cost = 0.5 * float(r @ r)
    history = getattr(res, "history", ())
    step = dict(history).get("parameter_step")
    if step is not None and len(step) == len(se):
        # the Gauss-Newton step left, in the parameters' own standard errors
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.abs(np.asarray(step) * sh.th_scale) / se
        history = tuple(history) + (("step_in_stderr", float(np.max(ratio)) if np.all(np.isfinite(ratio))
                                     else float("inf")),)
    status, message = fit_status(res.reason, res.success, message, warned=bool(warns), structure=structure,
                                 history=history, cost=cost, refined=refined)
    return FitResult(
        problem=problem, model=m.name, names=tuple(free), estimate=theta, stderr=se, initial=np.asarray(initial, float),
        corr=corr, cov=unc.cov, params=fitted, t=tuple(t_l), measured=tuple(meas_l), simulated=tuple(sim_l),
        residuals=tuple(res_l), nrmse=nrmse(names, Ym, Yp), sigma2=unc.sigma2, tau=unc.tau, cost=cost,
        nsub=problem.nsub, noise=dict(problem.noise), noise_source=dict(problem.noise_source), states=tuple(states),
        encoder_zero=tuple(zeros), input_corrections=tuple(corr_l), status=status, message=message, reason=res.reason,
        iterations=res.iterations, wall_time=time.perf_counter() - t_start, warnings=tuple(warns), at_bound=at_bound,
        active_constraints=active, condition=unc.condition, weak_directions=unc.weak,
        input_noise=dict(problem.input_noise), delay=o.extra_delay, guess_notes=problem.guess_notes, method=method,
        attempts=attempts, structure=structure, eps=o.eps, eps_source=problem.eps_source, eps_bias=unc.eps_bias,
        offset_error=unc.offset_error if offs else None, phase_parts=unc.phase_parts if offs else None,
        zero_corr=unc.zero_corr,
        integration=problem.integration.note)


def offset_phases(model, twists, dt: float, sensors) -> np.ndarray:
    """The constant offsets of angle differences taken as twists, each in its own standard deviations,
    as sums of the encoders' power-on phases, each independent, uniform within a tick, in ITS standard
    deviations (``q / sqrt(12)``): (len(twists), n_encoders), a difference ``a - b`` carrying ``a``'s
    phase minus ``b``'s."""
    encs = sorted({p for c in twists for p in c.parts})
    sd = np.array([channel_std(model, e, dt, sensors) for e in encs])
    D = np.zeros((len(twists), len(encs)))
    for k, c in enumerate(twists):
        D[k, encs.index(c.parts[0])] += 1.0
        D[k, encs.index(c.parts[1])] -= 1.0
    M = D * sd
    d = np.sqrt(np.sum(M ** 2, axis=1))
    return M / d[:, None] if np.all(d > 0) else np.eye(len(twists))


def offset_correlation(model, twists, dt: float, sensors) -> np.ndarray:
    """Correlation of the constant offsets of angle differences taken as twists (:func:`offset_phases`):
    two differences that share an encoder correlate (``+`` or ``-``)."""
    M = offset_phases(model, twists, dt, sensors)
    return M @ M.T
