"""What the benchmark runs: every (scenario, controller) at K switch-on phases and S noise seeds.

The switch-on phases are spread over ONE stick-slip period measured on the scenario's uncontrolled
run (:func:`reference_run`: the programme alone, the scenario's own seed): ``t_k = start + k T / K``.
A later switch-on lengthens the run by the same amount, so every run has the same controlled part.
A prevention scenario (control from t = 0) has no phase to vary: its K x S runs differ in their
noise seed only.

Every random number of a run comes from its seed, derived from (scenario seed, phase index, seed
index) by :class:`numpy.random.SeedSequence` (:func:`run_seed`): a run is bit-reproducible whichever
worker process runs it and in whichever order.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from models.errors import ConfigError
from models.signals import stick_slip_cycles
from mitigate.metrics import MetricOptions, moving_severity, programmed_speed, rig_period, windows
from mitigate.record import BenchmarkRun

__all__ = ["Reference", "RunTask", "reference_run", "make_tasks", "run_seed", "task_scenario", "slug"]


def slug(name: str) -> str:
    """A file-name-safe version of a name (lower case, ``[a-z0-9_]``)."""
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_") or "x"


def run_seed(scenario_seed: int, phase: int, seed: int) -> int:
    """The noise seed of one run: a 31-bit integer from (scenario seed, phase index, seed index)."""
    return int(np.random.SeedSequence([int(scenario_seed) & 0xFFFFFFFF, phase, seed]).generate_state(1)[0] >> 1)


@dataclass(frozen=True)
class Reference:
    """The uncontrolled run of a scenario (the programme alone).

    Attributes
    ----------
    scenario : its name
    period : the stick-slip period [s] the phases and the metric windows use
    period_source : "measured" (stick-slip cycles of the objective body before the switch-on),
        "spectrum" (its dominant frequency) or "rig" (the rig's estimate, :func:`models.modal.stick_slip_period`)
    prevention : the control starts at t = 0 (no stick-slip at the switch-on by design)
    stick_slip : the objective body sticks and slips in the period before the switch-on
    severity_before : severity of that period against the programmed speed [-]
    residual_severity : the uncontrolled run's residual severity (what a controller removes) [-]
    speed : (m,) the objective body's true speed in the uncontrolled run from t = 0 at the DAQ period
        [rad/s] (a run switched on at any phase is the same run until its switch-on: what it added is
        measured against this; not in :meth:`as_dict`)
    """

    scenario: str
    period: float
    period_source: str
    prevention: bool
    stick_slip: bool
    severity_before: float
    residual_severity: float
    speed: np.ndarray | None = field(default=None, repr=False, compare=False)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "speed"}


@dataclass(frozen=True)
class RunTask:
    """One closed-loop run of the benchmark (everything a worker needs, picklable).

    ``options`` are the controller's raw options (the suite's, or tuned ones); ``metrics`` has the
    scenario's measured ``period``; ``uncontrolled`` is the scenario's uncontrolled speed
    (:attr:`Reference.speed`).
    """

    scenario: object = field(repr=False)
    controller: str
    phase: int
    seed: int
    switch_on: float
    run_seed: int
    options: Mapping = field(default_factory=dict, repr=False)
    metrics: MetricOptions = field(default_factory=MetricOptions, repr=False)
    tag: str = ""
    uncontrolled: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def key(self) -> str:
        """``<scenario>/<controller>/p<phase>_s<seed>`` (file-name safe; ``tag`` prefixes it)."""
        base = f"{slug(self.scenario.name)}/{slug(self.controller)}/p{self.phase}_s{self.seed}"
        return f"{self.tag}/{base}" if self.tag else base

    def identity(self) -> BenchmarkRun:
        """Which run this is, for its record."""
        return BenchmarkRun(self.key, self.scenario.name, self.controller, self.phase, self.seed, self.switch_on,
                            self.run_seed, dict(self.options))


def reference_run(scenario, metrics: MetricOptions = MetricOptions()) -> Reference:
    """Run the programme alone and measure the stick-slip period and the state at the switch-on."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for
    from mitigate.controllers.pi import PIOnly, PIOptions

    sc = scenario
    try:
        t_rig = rig_period(sc.model, sc.model_params)
    except ConfigError:
        t_rig = float("nan")
    start = sc.control.start
    guess = t_rig if math.isfinite(t_rig) else sc.duration / 10
    extra = 2 * guess
    run = run_closed_loop(sc.replace(duration=sc.duration + extra, controllers=()),
                          PIOnly(PIOptions(), context_for(sc)))
    w = run.objective_speed
    dt = sc.dt
    wp = programmed_speed(sc, run.t)
    ref = float(np.nanmean(wp)) or 1.0
    stuck = metrics.stuck_speed if metrics.stuck_speed is not None else 1e-3 * abs(ref)
    prevention = start <= 0

    def sev(x):
        return float(moving_severity(x, dt, len(x) * dt, ref, stuck)[0]) if len(x) >= 2 else float("nan")

    lo, hi = (0.5 * start, start + extra) if not prevention else (0.5 * sc.duration, sc.duration + extra)
    seg = w[int(round(lo / dt)):int(round(hi / dt)) + 1]
    cyc = stick_slip_cycles(seg, dt, stuck) if run.success else None
    if cyc is not None:
        period, source = cyc.period, "measured"
    else:
        from models.signals import dominant_frequency
        f = dominant_frequency(seg, dt) if run.success else 0.0
        if f > 0 and sev(seg) > metrics.suppress_threshold:
            period, source = 1.0 / f, "spectrum"
        elif math.isfinite(t_rig):
            period, source = t_rig, "rig"
        else:
            raise ConfigError(f"{sc.where}: no stick-slip period: the uncontrolled run does not oscillate and "
                              f"rig {sc.model.name!r} has no torsional mode")
    # stick-slip at the switch-on: the body stuck at least once in the two periods before it, and the
    # severity of that stretch above the suppression threshold (a run that diverged has none)
    k0 = int(round(start / dt))
    before = w[max(0, k0 - int(round(2 * period / dt))):k0 + 1] if not prevention and k0 < len(w) else w[:0]
    sev_before = sev(before) if not prevention else 0.0
    slip_before = (not prevention and before.size > 0 and bool(np.any(np.abs(before) <= stuck))
                   and sev_before > metrics.suppress_threshold)
    n_res = int(round(windows(metrics, period, sc.duration - start, dt)[0] / dt))
    end = int(round(sc.duration / dt)) + 1
    tail = w[max(0, end - max(n_res, 2)):end] if run.success else w[:0]
    return Reference(sc.name, float(period), source, prevention, bool(slip_before), sev_before, sev(tail),
                     np.asarray(w, float) if run.success else None)


def task_scenario(task: RunTask):
    """The scenario of one run: switched on at ``task.switch_on`` (its duration lengthened by the
    shift), its noise from ``task.run_seed``, only the task's controller with the task's options."""
    from mitigate.scenario import ControllerSpec
    sc = task.scenario
    shift = max(0.0, task.switch_on - sc.control.start)
    spec = next(c for c in sc.controllers if c.name == task.controller)
    return sc.replace(duration=sc.duration + shift, control=sc.control.replace(start=task.switch_on),
                      seed=task.run_seed, sim=dataclasses.replace(sc.sim, seed=task.run_seed),
                      controllers=(ControllerSpec(spec.name, spec.kind, dict(task.options)),))


def make_tasks(suite, references: Mapping[str, Reference], *, phases: int, seeds: int,
               options: Mapping | None = None, controllers=None, tag: str = "") -> list[RunTask]:
    """Every run of the suite: scenario x controller x phase x seed.

    Parameters
    ----------
    references : ``{scenario: Reference}`` (the measured periods)
    options : ``{(scenario, controller): raw options}`` replacing the suite's (tuned values)
    controllers : restrict to these controller names (None: all)
    """
    if isinstance(phases, bool) or not isinstance(phases, int) or phases < 1:
        raise ConfigError(f"phases must be an integer >= 1, got {phases!r}")
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ConfigError(f"seeds must be an integer >= 1, got {seeds!r}")
    tasks = []
    for sc in suite.scenarios:
        ref = references[sc.name]
        mo = dataclasses.replace(suite.metrics, period=ref.period)
        for c in sc.controllers:
            if controllers is not None and c.name not in controllers:
                continue
            opts = dict((options or {}).get((sc.name, c.name), c.options))
            for k in range(phases):
                t_on = sc.control.start + (0.0 if ref.prevention else k * ref.period / phases)
                for j in range(seeds):
                    s = run_seed(sc.seed, k, j)
                    tasks.append(RunTask(sc, c.name, k, j, round(t_on, 9), s, opts, mo, tag, ref.speed))
    return tasks
