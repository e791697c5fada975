"""Estimation over a recorded log: :func:`estimate_log` -> :class:`EstimationResult`.

Runs any online estimator (:class:`estimators.base.StateEstimator`) over a log sample by
sample exactly as in a closed loop: ``update(t_k, measurement_k, u_{k-1})`` -- the inputs of
row ``k - 1`` are taken as held over the sample that ends at row ``k``, as a DAQ logs its
commands.  Row 0 of the result is the estimator's prior (:meth:`StateEstimator.prior`; NaN
when it has none).  ``mitigate estimate`` is this call plus argument parsing and writing.

Also here: :func:`log_channels` (which of a rig's measurement channels a log holds) and
:func:`true_twists` (the true twists a simulator's log carries, to score an estimate).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimators.base import EstimatorContext, StateEstimator
from estimators.online.factory import make_estimator
from estimators.online.channels import angle_combination, default_channels
from models.errors import ConfigError, DataError
from models.logs import TRUTH_PREFIX
from models.sensors import SensorOptions
from models.status import Outcome, Status

__all__ = ["EstimationResult", "estimate_log", "log_channels", "true_twists"]

#: windows of the log checked for observability: length [s] and at most how many
OBS_WINDOW_S = 4.0
OBS_WINDOWS_MAX = 12


@dataclass(frozen=True)
class EstimationResult(Outcome):
    """What an estimator made of a log (python-control style result; time on the first axis).

    Attributes
    ----------
    t : (N,) sample times [s] (row 0: the prior, at the log's first time)
    x, std : (N, nx) estimates and their standard deviations, in ``names`` order and ``units``
    names, units : state names (the rig's, then augmented unknowns) and their SI units
    channels : the measurement channels the estimator read
    kind : the estimator's kind ("ekf", "mhe", "fd", a plug-in's)
    corrected, warned, succeeded : (N,) bool flags of each estimate (a measurement update was
        applied; its status was WARNING; its status succeeded).  Row 0: not corrected, succeeded.
    step_times : (N - 1,) wall time of each update [s]
    counts : the estimator's counts (steps, dropouts, failures, fallbacks)
    observability : one line: what the configuration can know (construction-time checks)
    observability_reports : {"observability" | "observability_steady": ObservabilityReport}
    observability_along_log : windows checked along the estimates, how many showed the twist,
        the worst window's message (empty when the estimator checks none)
    compile_status : how the step functions were built (None: nothing compiled)
    status : :meth:`Status.worst` of the estimates (WARNING when some warned or fell back)
    message : the counts of warned and fallback estimates, or "ok"
    """

    t: np.ndarray
    x: np.ndarray
    std: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...]
    channels: tuple[str, ...]
    kind: str
    corrected: np.ndarray
    warned: np.ndarray
    succeeded: np.ndarray
    step_times: np.ndarray
    counts: dict
    observability: str
    observability_reports: dict = field(default_factory=dict)
    observability_along_log: dict = field(default_factory=dict)
    compile_status: str | None = None
    status: Status = Status.OK
    message: str = "ok"

    def state(self, name: str) -> np.ndarray:
        """One state's estimates (N,), by name."""
        if name not in self.names:
            raise ConfigError(f"state must be one of {', '.join(self.names)}, got {name!r}")
        return self.x[:, self.names.index(name)]

    def rmse(self, name: str, truth, *, after: float = 0.0) -> float:
        """RMSE of one state's estimates against ``truth`` (N,) over the samples after the prior
        with ``t >= t[0] + after`` [s] (in the state's unit)."""
        truth = np.asarray(truth, float).ravel()
        if truth.shape != self.t.shape:
            raise DataError(f"truth of {name!r} must have {self.t.size} samples, got {truth.size}")
        keep = self.t[1:] >= self.t[0] + after
        err = self.state(name)[1:][keep] - truth[1:][keep]
        return float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan")


def log_channels(model, log) -> list[str]:
    """The rig's measurement channels present (and not derived) in ``log``, without a lone angle
    (one angle carries no twist).

    Raises
    ------
    DataError : the log holds none of the rig's measurement channels
    """
    known = default_channels(model)
    chans = [c for c in known if c in log and c not in log.derived]
    angles = [c for c in chans if model.sensor_of(c).kind == "encoder" and model.sensor_of(c).channels[0] == c]
    if len(angles) == 1:
        chans.remove(angles[0])
    if not chans:
        raise DataError(f"{log.source}: no measurement column of rig {model.name!r}; expected some of "
                        f"{', '.join(known)}")
    return chans


def true_twists(log, model) -> dict[str, np.ndarray]:
    """True twists in a log, by estimator state name: ``true_twist_<spring>`` columns (our simulator;
    ``twist_<spring>`` in older logs), or ``twist<a><b>`` meaning ``theta<a> - theta<b>`` (the
    independent simulator) when that difference is one spring's twist."""
    out = {}
    twists = [s for s in model.states if s.startswith("twist_")]
    for name in twists:
        for col in (TRUTH_PREFIX + name, name):
            if col in log and name not in out:
                out[name] = log[col]

    def comb(ch):
        s = model.sensor_of(ch)
        if s is None or s.kind != "encoder" or s.channels[0] != ch:
            return None
        return angle_combination(model, s.target)

    for col in log.channels:
        if not col.startswith("twist") or col in out or col.startswith("twist_"):
            continue
        digits = col[len("twist"):]
        if len(digits) != 2 or not digits.isdigit():
            continue
        ca_, cb = comb(f"theta{digits[0]}"), comb(f"theta{digits[1]}")
        if ca_ is None or cb is None:
            continue
        d = ca_ - cb
        nz = np.flatnonzero(np.abs(d) > 1e-12)
        if nz.size == 1 and model.states[nz[0]] in twists and model.states[nz[0]] not in out:
            out[model.states[nz[0]]] = d[nz[0]] * log[col]
    return out


def estimate_log(log, estimator, model=None, params=None, *, sensors: SensorOptions | None = None,
                 where: str = "estimator", along: bool = True) -> EstimationResult:
    """Run an online estimator over a log.

    Parameters
    ----------
    log : a :class:`models.logs.Log` (e.g. :func:`models.logs.read_csv`) holding the rig's inputs
        and some of its sensor channels
    estimator : a built :class:`estimators.base.StateEstimator`, or a spec for
        :func:`estimators.online.factory.make_estimator` (a kind such as ``"ekf"``, or a table
        ``{"kind": "mhe", "window": 20, ...}``; without ``channels`` the rig's channels in the log,
        :func:`log_channels`)
    model : the rig (a :class:`models.rig.RigModel` or a name/path for :func:`models.rig.get_model`);
        default the built estimator's
    params : the parameters the estimator believes (default the rig's published set); only for a spec
    sensors : sensor settings for a spec (default :class:`models.sensors.SensorOptions`)
    where : prefix of error messages
    along : check the observability along the estimated run, in windows (``EstimationResult.along``);
        False skips it (a caller that only wants the states: at 2 kHz a 4 s window is an 8000-sample
        Jacobian stack)

    Returns
    -------
    EstimationResult

    Raises
    ------
    ConfigError : a bad spec; DataError : an input or a channel the estimator reads is missing
    from the log; PluginError : the estimator raised or returned nonsense (its run fails)
    """
    if isinstance(estimator, StateEstimator):
        if params is not None or sensors is not None:
            raise ConfigError(f"{where}: params and sensors apply to an estimator spec, not to a built estimator")
        model = estimator.context.model if model is None else model
    elif model is None:
        raise ConfigError(f"{where}: a model is needed to build an estimator from a spec, got none")
    if isinstance(model, str):
        from models.rig import get_model
        model = get_model(model)
    for n in model.inputs:
        if n not in log:
            raise DataError(f"{log.source}: missing input column {n!r} of rig {model.name!r} (inputs: "
                            f"{', '.join(model.inputs)})")
    est = estimator
    if not isinstance(est, StateEstimator):
        spec = {"kind": est} if isinstance(est, str) else dict(est)
        if spec.get("kind") != "fd" and "channels" not in spec:
            spec["channels"] = log_channels(model, log)
        params = model.published() if params is None else params
        est = make_estimator(spec, EstimatorContext(model, params, log.dt, sensors or SensorOptions(), where=where))
    missing = [c for c in est.channels if c not in log]
    if missing:
        raise DataError(f"{log.source}: the estimator reads column {missing[0]!r}, not in the log "
                        f"(it reads {', '.join(est.channels)})")

    n = len(log.t)
    U = np.column_stack([log[name] for name in model.inputs])
    chan = {c: log[c] for c in est.channels}
    names = tuple(est.names)
    X = np.full((n, len(names)), np.nan)
    S = np.full((n, len(names)), np.nan)
    corrected, warned, succeeded = np.zeros(n, bool), np.zeros(n, bool), np.ones(n, bool)
    prior = est.prior()
    if prior is not None:
        X[0], S[0] = prior.x, np.sqrt(np.maximum(np.diag(prior.P), 0.0))
    times = np.zeros(max(n - 1, 0))
    statuses = []
    for k in range(1, n):
        e = est.update(float(log.t[k]), {c: v[k] for c, v in chan.items()}, U[k - 1])
        X[k] = e.x
        S[k] = np.sqrt(np.maximum(np.diag(e.P), 0.0))
        corrected[k], warned[k], succeeded[k] = e.corrected, e.status is Status.WARNING, e.success
        times[k - 1] = e.solve_time
        statuses.append(e.status)

    reports = {nm: rep for nm in ("observability", "observability_steady")
               if (rep := getattr(est, nm)) is not None}
    U_held = np.vstack([U[:1], U[:-1]])           # row k: the input over the sample ending at k
    along = {}
    reps = est.observability_windows(X, U_held, window=OBS_WINDOW_S, max_windows=OBS_WINDOWS_MAX) if along else []
    if reps:
        worst = max(reps, key=lambda r: float(np.max(r.twist_std / r.scales[[r.names.index(t)
                                                                              for t in r.twist_names]])))
        along = {"windows": len(reps), "window_s": reps[0].samples * log.dt,
                 "twist_observable_windows": int(sum(r.twist_observable for r in reps)), "worst": worst.message}
    status = Status.worst(statuses)
    nwarn, nfall = int(warned.sum()), int(sum(s is Status.FALLBACK for s in statuses))
    message = "ok" if status is Status.OK else (f"{nwarn} of {n - 1} estimates warned, {nfall} came from the "
                                                 f"fallback")
    return EstimationResult(np.asarray(log.t, float), X, S, names, tuple(est.units), tuple(est.channels), est.kind,
                            corrected, warned, succeeded, times, est.counts.as_dict(), est.observability_message,
                            reports, along, est.compile_status, status, message)
