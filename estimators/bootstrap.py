"""Parametric-bootstrap error bars and bias correction for :func:`estimators.identify.identify`.

The Gauss-Newton standard errors of a fit assume white Gaussian output noise and exact
inputs.  Real and simulated rig logs break both: 1000-tick encoders quantise the angles
(speeds from backward differences then carry a 0.63 rad/s count), the load cells put noise on
the logged normal forces that the model takes as exact (an error in the variables), and the
fitted model regularises the friction the plant sticks with.  Each of these biases the
estimates by more than the statistical error bar (BENCHMARKS.md, identification).

The parametric bootstrap measures those effects instead of assuming them away:

1. simulate the exact stick/slip plant (:func:`models.plant.simulate`) with the
   *fitted* parameters, from the fitted initial state, driven by the logged inputs, through
   the sensor model (encoders, load-cell noise) with a fresh seed per replicate;
2. fit every replicate exactly as the original log was fitted: same options, from the same
   initial guess (``start="initial"``, so the replicates repeat the whole pipeline, local
   minima included; ``start="fit"`` starts at the fitted values), state nodes initialised
   from the replicate itself as for any log (a replicate driven by a logged motor torque
   drifts away from the original's trajectory; warm-starting its nodes from the original fit
   left rig2's replicates unconverged and biased);
3. the spread of the replicate estimates is the sampling error of the whole pipeline, and
   their mean offset from the fitted values is its bias at these parameters.

The error bar reported is the bootstrap's root-mean-square error of the estimator,
``sqrt(bias^2 + sd^2)``: it covers what the pipeline gets wrong systematically as well as its
scatter.  A bias-corrected value ``theta_hat - bias`` is reported too, for information only: with
a handful of replicates its own scatter (``sd sqrt(1 + 1/B)``) is often larger than the bias it
removes (BENCHMARKS.md), so the fitted value stays the estimate.

Normal-force inputs (unit N: pin forces, the lead screw's axial force, set by servos and
springs, so slow) are low-passed (zero-phase, ``force_cutoff``) to serve as the true forces; the
replicate's sensors add fresh load-cell noise to them.  Other inputs (a motor torque that follows a
speed loop, a measured drive speed, a set-point) are replayed as logged: a low-pass would remove
real content, and their noise then only excites the replica a little more than the rig.

This is as good as the simulator's account of the rig: on simulated logs it reproduces the
data-generating process; on a real rig the sensor options must describe its sensors.  It
measures the pipeline's bias at the FITTED parameters; where that bias changes abruptly with the
parameters (a cost with several minima, as rig2's damping c in the seed-001 setting) or where the
logged input was produced in closed loop from the noisy measurements (rig2's motor torque from a
PI loop, replayed open loop here), the replicates do not reproduce the original error and the
error bar can be too small (BENCHMARKS.md).
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from models import get_model
from models.errors import ConfigError, DataError
from models.logs import Log
from models.sensors import SensorOptions
from models.plant import SimOptions, simulate

__all__ = ["BootstrapOptions", "BootstrapResult", "bootstrap"]


@dataclass(frozen=True, kw_only=True)
class BootstrapOptions:
    """Options of :func:`bootstrap`.

    Parameters
    ----------
    replicates : number of simulated replicate logs B (>= 2)
    seed : seed of the first replicate's sensor noise (replicate b uses ``seed + b``)
    sensors : the rig's sensors (encoder ticks, load-cell noise); default the reference rig's
    force_cutoff : low-pass [Hz] applied to normal-force inputs (unit N) to obtain the true forces;
        None: replay them as logged
    sim_nsub : substeps per sample of the exact plant (stick/slip switching resolves to dt/sim_nsub)
    max_iter : iteration limit of each replicate fit (None: the original fit's)
    start : where each replicate fit starts: "initial" (the original fit's initial guess, so the
        replicates repeat the whole pipeline, local minima included) or "fit" (the fitted values:
        faster, but blind to where the optimiser stops)
    workers : processes (1: in this process)
    progress : progress bar (tqdm) on stderr
    """

    replicates: int = 8
    seed: int = 1000
    sensors: SensorOptions = SensorOptions()
    force_cutoff: float | None = 2.0
    sim_nsub: int = 10
    max_iter: int | None = None
    start: str = "initial"
    workers: int = 1
    progress: bool = False

    def __post_init__(self):
        for name, least in (("replicates", 2), ("sim_nsub", 1), ("max_iter", 1), ("workers", 1)):
            v = getattr(self, name)
            if name == "max_iter" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise ConfigError(f"bootstrap.{name} must be an integer >= {least}, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ConfigError(f"bootstrap.seed must be an integer, got {self.seed!r}")
        fc = self.force_cutoff
        if fc is not None and (isinstance(fc, bool) or not (isinstance(fc, (int, float)) and np.isfinite(fc)
                                                            and fc > 0)):
            raise ConfigError(f"bootstrap.force_cutoff must be a frequency > 0 Hz, got {fc!r}")
        if self.start not in ("initial", "fit"):
            raise ConfigError(f"bootstrap.start must be 'initial' or 'fit', got {self.start!r}")
        if not isinstance(self.sensors, SensorOptions):
            raise ConfigError(f"bootstrap.sensors must be SensorOptions, got {type(self.sensors).__name__}")


@dataclass(frozen=True)
class BootstrapResult:
    """Result of :func:`bootstrap` (SI units; parameters in ``names`` order).

    Attributes
    ----------
    names : fitted parameter names
    estimate : the original fit's estimates
    replicates : (B_ok, n) estimates of the replicate fits that returned finite values
    bias : mean(replicates) - estimate, the pipeline's bias at the fitted parameters
    sd : standard deviation of the replicates (ddof = 1)
    error : ``sqrt(bias^2 + sd^2)``, the root-mean-square error: the reported error bar
    corrected : estimate - bias (information only), with standard error ``sd sqrt(1 + 1/B_ok)``
    corrected_stderr : that standard error
    unconverged : replicate fits that stopped without their convergence test (kept: dropping them
        would select the easy noise realisations)
    failures : replicate simulations or fits that raised or returned non-finite values (excluded)
    status, success, wall_time [s]
    """

    names: tuple
    estimate: np.ndarray
    replicates: np.ndarray
    bias: np.ndarray
    sd: np.ndarray
    error: np.ndarray
    corrected: np.ndarray
    corrected_stderr: np.ndarray
    unconverged: int
    failures: int
    status: str
    success: bool
    wall_time: float

    def as_dict(self) -> dict:
        return {"names": list(self.names), "estimate": self.estimate.tolist(), "bias": self.bias.tolist(),
                "sd": self.sd.tolist(), "error": self.error.tolist(), "corrected": self.corrected.tolist(),
                "corrected_stderr": self.corrected_stderr.tolist(), "replicates": int(self.replicates.shape[0]),
                "unconverged": self.unconverged, "failures": self.failures,
                "status": self.status, "success": self.success, "wall_time_s": self.wall_time}


def _normal_force(unit: str) -> bool:
    return unit == "N"


def _replicate_inputs(log: Log, model, n_rows: int, input_row: str, cutoff: float) -> np.ndarray:
    """(n_rows - 1, nu) inputs applied over each sample interval: logged inputs, forces low-passed."""
    from scipy.signal import butter, filtfilt

    cols = []
    nyq = 0.5 / log.dt
    for name, unit in zip(model.inputs, model.input_units):
        x = np.asarray(log[name], dtype=float)[:n_rows]
        if cutoff is not None and _normal_force(unit) and cutoff < nyq and x.size > 9:
            b, a = butter(2, cutoff / nyq)
            x = filtfilt(b, a, x)
        cols.append(x)
    U = np.column_stack(cols)
    return U[1:] if input_row == "end" else U[:-1]


def _one_replicate(args):
    """Simulate replicate ``b`` of every log and fit it; returns (estimates, converged) or None."""
    from estimators.identify import identify  # local: keeps the module light for process workers

    (b, model_name, params, start, logs, n_rows, x0s, options, boot) = args
    m = get_model(model_name)
    reps = []
    for j, (lg, n, x0) in enumerate(zip(logs, n_rows, x0s)):
        U = _replicate_inputs(lg, m, n, options.input_row, boot.force_cutoff)
        sim = simulate(m, params, U, (n - 1) * lg.dt,
                       SimOptions(dt=lg.dt, nsub=boot.sim_nsub, seed=boot.seed + 7919 * b + j),
                       sensors=boot.sensors, x0=x0)
        if not sim.success:
            return None
        reps.append(sim.to_log())
    opts = replace(options, input_row="end", max_iter=boot.max_iter or options.max_iter, systematic=False,
                   progress=False)
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # identifiability warnings of replicates repeat the original's
            fit = identify(reps, m, start, opts, _validate=False)
    except Exception:  # noqa: BLE001 - a failed replicate is counted, not fatal
        return None
    if not np.all(np.isfinite(fit.estimate)):
        return None
    return np.asarray(fit.estimate, dtype=float), bool(fit.success)


def bootstrap(fit, logs: Log | list[Log], options, boot: BootstrapOptions = BootstrapOptions()) -> BootstrapResult:
    """Parametric bootstrap of a fit (see the module docstring).

    Parameters
    ----------
    fit : :class:`estimators.identify.FitResult` of ``logs`` with ``options``
    logs : the log(s) that were fitted (the training part is taken from ``fit``)
    options : the :class:`estimators.identify.IdentifyOptions` of the fit
    boot : :class:`BootstrapOptions`

    Returns
    -------
    BootstrapResult (``success`` False if fewer than two replicate fits succeeded)
    """
    t0 = time.perf_counter()
    logs = [logs] if isinstance(logs, Log) else list(logs)
    if len(logs) != len(fit.t):
        raise DataError(f"bootstrap: the fit used {len(fit.t)} log(s), got {len(logs)}")
    m = get_model(fit.model)
    n_rows = [len(t) + 1 for t in fit.t]            # rows of each log the fit used
    x0s = [np.asarray(s[0], dtype=float) for s in fit.states]
    logs = [lg.with_speeds() for lg in logs]
    start = fit.params if boot.start == "fit" else fit.params.with_vector(fit.names, fit.initial)
    jobs = [(b, m.name, fit.params, start, logs, n_rows, x0s, options, boot) for b in range(boot.replicates)]
    results = []
    bar = None
    if boot.progress:
        from tqdm import tqdm
        bar = tqdm(total=len(jobs), desc=f"bootstrap {m.name}", unit="fit")
    if boot.workers > 1:
        with ProcessPoolExecutor(max_workers=boot.workers) as ex:
            for r in ex.map(_one_replicate, jobs):
                results.append(r)
                if bar is not None:
                    bar.update()
    else:
        for job in jobs:
            results.append(_one_replicate(job))
            if bar is not None:
                bar.update()
    if bar is not None:
        bar.close()
    ok = [r for r in results if r is not None]
    failures = len(results) - len(ok)
    unconverged = sum(1 for r in ok if not r[1])
    est = np.asarray(fit.estimate, dtype=float)
    nan = np.full(est.shape, np.nan)
    if len(ok) < 2:
        return BootstrapResult(tuple(fit.names), est, np.empty((len(ok), est.size)), nan, nan, nan, nan, nan,
                               unconverged, failures, f"only {len(ok)} of {len(results)} replicate fits returned "
                               f"estimates", False, time.perf_counter() - t0)
    R = np.vstack([r[0] for r in ok])
    bias = R.mean(axis=0) - est
    sd = R.std(axis=0, ddof=1)
    status = f"{len(ok)} replicates" + (f", {unconverged} unconverged" if unconverged else "") + \
        (f", {failures} failed" if failures else "")
    return BootstrapResult(tuple(fit.names), est, R, bias, sd, np.hypot(bias, sd), est - bias,
                           sd * np.sqrt(1 + 1 / len(ok)), unconverged, failures, status, True,
                           time.perf_counter() - t0)
