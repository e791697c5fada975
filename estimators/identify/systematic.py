"""The systematic error of a fit from its regularisation: ``|theta(eps) - theta(eps/2)|``.

The fit's model smooths each contact's sign with width ``eps`` (or a law's own smoothing rate,
such as the lead screw's ``r1``).  Refitting with that smoothing halved, warm-started from the
fit, shows how much the estimates owe to it; ``FitResult.syserr`` holds the difference and the
fitted set's standard errors become the total ``sqrt(stderr^2 + syserr^2)``.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from estimators.identify.result import FitResult, IdentifiabilityWarning
from models.errors import SolverFailure
from models.friction import get_law

__all__ = ["systematic_error"]


def _smoothing_params(model) -> list[str]:
    """The rig parameters that set a law's own smoothing rate."""
    out = []
    for c in model.spec.contacts:
        sp_name = get_law(c.law).smoothing_param
        ref = dict(c.params).get(sp_name) if sp_name else None
        if ref is not None and ref.kind == "param":
            out.append(ref.name)
    return sorted(set(out))


def systematic_error(problem, fit: FitResult) -> FitResult:
    """``fit`` with ``syserr`` and the total errors (:attr:`FitResult.error`; a warm refit with the regularisation
    halved; a law with its own smoothing rate: that rate doubled).

    A refit that fails leaves ``syserr`` NaN and says so in ``warnings``; a free smoothing rate
    has no systematic error to estimate (said so too).
    """
    o, free = problem.options, problem.free
    start, eps2, msg = fit.params, o.eps / 2, ""
    smoothing = _smoothing_params(problem.model)
    if any(n in o.free for n in smoothing):
        msg = (f"systematic error not estimated: the regularisation rate {', '.join(smoothing)} is itself a free "
               f"parameter")
        return replace(fit, syserr=np.full(len(free), np.nan), warnings=fit.warnings + (msg,))
    if smoothing:
        start = start.replace(**{n: 2 * start[n] for n in smoothing})
        eps2 = o.eps
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            p2 = problem.derive(initial=start, eps=eps2, nsub=None if o.nsub is None else 2 * o.nsub,
                                systematic=False, detect_delay=0, max_iter=o.systematic_iter, progress=False)
            fit2 = p2.fit_once(fit)
    except SolverFailure as exc:
        fit2, msg = None, f"systematic error not estimated: the refit failed ({exc})"
    if fit2 is None:
        syserr = np.full(len(free), np.nan)
    else:
        syserr = np.abs(fit2.estimate - fit.estimate)
        if not fit2.success:
            msg = f"systematic error from an unconverged refit ({fit2.message.split('.')[0]})"
    total = replace(fit, syserr=syserr).error          # with the encoders' power-on phase, if any
    params = fit.params.with_meta(stderr=tuple((n, float(s)) for n, s in zip(free, total) if np.isfinite(s)))
    w = fit.warnings + ((msg,) if msg else ())
    if msg:
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=3)
    return replace(fit, syserr=syserr, params=params, warnings=w)
