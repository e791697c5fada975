"""Parametric-bootstrap error bars of a fit: ``bootstrap(fit)``.

The Gauss-Newton standard errors assume white Gaussian output noise and exact inputs.  Rig
logs break both: encoders quantise the angles, load cells put noise on logged normal forces
(an error in the variables), and the fitted model regularises the friction the plant sticks
with.  Each of these biases the estimates by more than the statistical error bar.

The parametric bootstrap measures those effects instead of assuming them away:

1. simulate the exact stick/slip plant (:func:`models.plant.simulate`) with the FITTED
   parameters, from the fitted initial state of every log, driven by the logged inputs
   (corrected through the fitted load-cell offsets and gains; forces low-passed at
   ``force_cutoff`` and encoder-measured drive speeds at ``speed_cutoff`` to serve as the true
   inputs; commands and other inputs replayed as logged), through the rig's sensor models
   (encoders, load-cell noise, delays) with a fresh seed per replicate;
2. fit every replicate exactly as the original was fitted: the same problem
   (``fit.problem.refit(logs=replicates)``), from the same start (``start="initial"``: the
   original initial set, or a new data-derived guess if the original had none, so the
   replicates repeat the whole pipeline; ``start="fit"``: the fitted values);
3. the spread of the replicate estimates is the pipeline's sampling error, and their mean
   offset from the fitted values its bias at these parameters.

The error bar reported is the root-mean-square error ``sqrt(bias^2 + sd^2)``.  A bias-corrected
value ``estimate - bias`` is reported for information only (its own scatter
``sd sqrt(1 + 1/B)`` is often larger than the bias it removes).  It is as good as the plant's
account of the rig; where the bias changes abruptly with the parameters, or the logged input
came from a closed loop on the noisy measurements (replayed open loop here), the error bar can
be too small (benchmarks/results/identify.md).
"""

from __future__ import annotations

import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from models.checks import check_options, option, prefix
from models.errors import ConfigError, DataError
from models.plant import SimOptions, simulate
from models.sensors import SensorOptions
from models.signals import lowpass
from models.status import Outcome, Status

__all__ = ["BootstrapOptions", "BootstrapResult", "bootstrap"]


@dataclass(frozen=True, kw_only=True)
class BootstrapOptions:
    """Options of :func:`bootstrap`.

    Parameters
    ----------
    replicates : number of simulated replicate logs B (>= 2)
    seed : seed of the first replicate's sensor noise (replicate b uses ``seed + 7919 b + log``)
    sensors : noise scale and quantisation of the replicates' sensors (the rig file's sensors)
    force_cutoff : low-pass [Hz] of the force inputs (load cells) to obtain the true forces; None: replay
        as logged
    speed_cutoff : low-pass [Hz] of speed inputs measured by an encoder (a speed drive's: quantised
        backward differences) to obtain the true drive speed; None: replay as logged
    sim_nsub : substeps per sample of the exact plant
    max_iter : iteration limit of each replicate fit (None: the original's)
    start : "initial" (the original start: repeats the whole pipeline) or "fit" (the fitted values)
    workers : processes (1: in this process)
    progress : progress bar (tqdm) on stderr
    """

    replicates: int = option(8, lo=2)
    seed: int = option(1000)
    sensors: SensorOptions = option(SensorOptions(), table=SensorOptions, what="SensorOptions")
    force_cutoff: float | None = option(2.0, lo=0.0, lo_open=True, unit="Hz", none=True)
    speed_cutoff: float | None = option(5.0, lo=0.0, lo_open=True, unit="Hz", none=True)
    sim_nsub: int = option(10, lo=1)
    max_iter: int | None = option(None, kind="integer", lo=1, none=True)
    start: str = option("initial", choices=("initial", "fit"))
    workers: int = option(1, lo=1)
    progress: bool = option(False)

    def __post_init__(self):
        check_options(self, prefix("bootstrap"))


@dataclass(frozen=True)
class BootstrapResult(Outcome):
    """Result of :func:`bootstrap` (SI units; parameters in ``names`` order).

    Attributes
    ----------
    names : fitted parameter names; estimate : the original fit's estimates
    replicates : (B_ok, n) estimates of the replicate fits that returned finite values
    bias : mean(replicates) - estimate; sd : their standard deviation (ddof 1)
    error : ``sqrt(bias^2 + sd^2)``, the reported error bar
    corrected : estimate - bias (information only), corrected_stderr : ``sd sqrt(1 + 1/B_ok)``
    unconverged : replicate fits that stopped without converging (kept)
    failures : replicate simulations or fits that failed (excluded)
    status : :class:`models.status.Status` (OK, WARNING with unconverged/failed replicates, FAILED
        with fewer than two estimates); message : detail; wall_time [s]
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
    status: Status
    message: str
    wall_time: float

    def as_dict(self) -> dict:
        return {"names": list(self.names), "estimate": self.estimate.tolist(), "bias": self.bias.tolist(),
                "sd": self.sd.tolist(), "error": self.error.tolist(), "corrected": self.corrected.tolist(),
                "corrected_stderr": self.corrected_stderr.tolist(), "replicates": int(self.replicates.shape[0]),
                "unconverged": self.unconverged, "failures": self.failures, "status": self.status.value,
                "message": self.message, "success": self.success, "wall_time_s": self.wall_time}


def _replicate_inputs(problem, fit, j: int, boot) -> tuple[np.ndarray, np.ndarray]:
    """(model inputs held over each training sample of log ``j``, its fitted initial state)."""
    m = problem.model
    d = problem.data[j]
    M = problem.options.shoot_every
    n_int = d.nint * M
    U = d.U[1:n_int + 1] if problem.options.input_row == "end" else d.U[:n_int]
    P = m.unpack(fit.params.vector())
    Um = np.array(m.input_from_measured([U[:, i] for i in range(m.nu)], P), float).T.reshape(n_int, m.nu)
    for i, (name, kind) in enumerate(zip(m.inputs, m.input_kinds)):
        s = m.sensor_of(name)
        cutoff = boot.force_cutoff if kind == "force" else \
            boot.speed_cutoff if (kind == "speed" and s is not None and s.kind == "encoder") else None
        if cutoff is not None and cutoff < 0.5 / problem.dt and n_int > 9:
            Um[:, i] = lowpass(Um[:, i], problem.dt, cutoff)
    return Um, np.asarray(fit.states[j][0], float)


def _one_replicate(args):
    """Simulate replicate ``b`` of every log and fit it: (estimates, converged) or None."""
    b, problem, fit_params, start, inputs, boot = args
    m = problem.model
    reps = []
    for j, (U, x0) in enumerate(inputs):
        sim = simulate(m, fit_params, U, U.shape[0] * problem.dt,
                       SimOptions(dt=problem.dt, nsub=boot.sim_nsub, seed=boot.seed + 7919 * b + j),
                       sensors=boot.sensors, actuators=False, x0=x0)
        if not sim.success:
            return None
        reps.append(sim.to_log())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the replicates' identifiability warnings repeat the original's
            rp = problem.derive(logs=reps, initial=start, holdout=0.0, input_row="end", extra_delay=0,
                                detect_delay=0, systematic=False, progress=False,
                                max_iter=boot.max_iter or problem.options.max_iter)
            fit = rp.solve()
    except Exception:  # noqa: BLE001 - a failed replicate is counted, not fatal
        return None
    if not np.all(np.isfinite(fit.estimate)):
        return None
    return np.asarray(fit.estimate, dtype=float), bool(fit.success)


def bootstrap(fit, options: BootstrapOptions | None = None) -> BootstrapResult:
    """Parametric bootstrap of ``fit`` (see the module docstring).

    Parameters
    ----------
    fit : a :class:`~estimators.identify.result.FitResult` (it carries its problem)
    options : :class:`BootstrapOptions`

    Returns
    -------
    BootstrapResult (status FAILED if fewer than two replicate fits returned estimates)
    """
    t0 = time.perf_counter()
    options = BootstrapOptions() if options is None else options
    if not isinstance(options, BootstrapOptions):
        raise ConfigError(f"options must be BootstrapOptions, got {type(options).__name__}")
    problem = getattr(fit, "problem", None)
    if problem is None:
        raise DataError("bootstrap needs a FitResult that carries its problem (from identify or problem.solve)")
    boot = options
    inputs = [_replicate_inputs(problem, fit, j, boot) for j in range(len(problem.data))]
    start = fit.params if boot.start == "fit" else problem.given_initial
    jobs = [(b, problem, fit.params, start, inputs, boot) for b in range(boot.replicates)]
    results = []
    bar = None
    if boot.progress:
        from tqdm import tqdm
        bar = tqdm(total=len(jobs), desc=f"bootstrap {problem.model.name}", unit="fit")
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
                               unconverged, failures, Status.FAILED,
                               f"only {len(ok)} of {len(results)} replicate fits returned estimates",
                               time.perf_counter() - t0)
    R = np.vstack([r[0] for r in ok])
    bias = R.mean(axis=0) - est
    sd = R.std(axis=0, ddof=1)
    message = f"{len(ok)} replicates" + (f", {unconverged} unconverged" if unconverged else "") + \
        (f", {failures} failed" if failures else "")
    status = Status.WARNING if (unconverged or failures) else Status.OK
    return BootstrapResult(tuple(fit.names), est, R, bias, sd, np.hypot(bias, sd), est - bias,
                           sd * np.sqrt(1 + 1 / len(ok)), unconverged, failures, status, message,
                           time.perf_counter() - t0)
