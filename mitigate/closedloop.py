"""The closed loop: plant simulator, sensors, estimator and controller at the DAQ rate.

One sample ``k`` (time ``t_k = k dt``)::

    y_k    = DAQ measurement at t_k (sensor models: quantised encoders, noisy load cells)
    xhat_k = estimator.update(y_k, u over [t_{k-1}, t_k], t_k)
    a_k    = controller.step(t_k, xhat_k, y_k)   if t_k >= control_start and every
             ``control_every`` samples from there, else the held action; before
             control_start the baseline (a): programmed set-point, programmed N2
    u_k    = [a_k.omega_ref, N1 programme(t_k), a_k.n2]  held over [t_k, t_{k+1}]
    plant  <- one exact stick/slip step (servo lag on N2, parameter mismatch)

Controllers and estimators see only measurements, estimates and the nominal
``scenario.model_params``; the true state and the true (mismatched) parameters stay in
the plant.  The input given to the estimator is the commanded set-point with the
MEASURED pin forces (load cells), because the servo output is not known exactly.
A failing controller or estimator is handled by their base classes (counted
fallbacks); a failing plant step ends the run with ``success = False`` and the
samples so far.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from estimators.factory import make_estimator
from models.rigs import get_model
from models.plant import Plant
from models.logs import Log
from models.errors import ConfigError

__all__ = ["ClosedLoopResult", "run_closed_loop", "baseline_input"]

MEAS_CHANNELS = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3", "motor_torque", "n1", "n2", "omega_ref")


@dataclass(frozen=True)
class ClosedLoopResult:
    """One closed-loop run; time on axis 0 (``n + 1`` samples unless the plant failed).

    Attributes
    ----------
    t : (n+1,) times [s]
    x : (n+1, nx) TRUE plant states (rig3 order: phi12, phi23, omega1..3, i, z)
    y : measured channels, each (n+1,) (what the DAQ recorded)
    xhat : (n+1, nxe) state estimates; ``xhat_names`` their names
    action_n2, action_omega_ref : (n+1,) controller commands held over [t_k, t_{k+1}] [N], [rad/s]
    u : (n+1, nu) inputs applied to the plant (servo output for n2; last row repeated)
    controller_active : (n+1,) bool, the controller was in charge at that sample
    controller_ok : (n+1,) bool, the held action did not come from a fallback
    solve_times : (m,) wall time of each controller call [s]
    plan_calls : (m,) bool, that call computed a new action (not a zero-order hold between the plans
        of a multi-rate controller such as the NMPC)
    estimator_times : (n+1,) wall time of each estimator update [s]
    controller_counts, estimator_counts : counts from the base classes
    status : human-readable; success : the plant ran to the end with finite states
    """

    t: np.ndarray
    x: np.ndarray
    y: dict = field(repr=False)
    xhat: np.ndarray = field(repr=False)
    xhat_names: tuple = ()
    action_n2: np.ndarray = field(default=None, repr=False)
    action_omega_ref: np.ndarray = field(default=None, repr=False)
    u: np.ndarray = field(default=None, repr=False)
    controller_active: np.ndarray = field(default=None, repr=False)
    controller_ok: np.ndarray = field(default=None, repr=False)
    solve_times: np.ndarray = field(default=None, repr=False)
    plan_calls: np.ndarray = field(default=None, repr=False)
    estimator_times: np.ndarray = field(default=None, repr=False)
    controller_counts: dict = field(default_factory=dict)
    estimator_counts: dict = field(default_factory=dict)
    controller: str = ""
    states: tuple = ()
    inputs: tuple = ()
    control_start: float = 0.0
    status: str = "ok"
    success: bool = True

    def state(self, name: str) -> np.ndarray:
        """True state trajectory by name."""
        return self.x[:, self.states.index(name)]

    def input(self, name: str) -> np.ndarray:
        """Applied input trajectory by name."""
        return self.u[:, self.inputs.index(name)]

    def to_log(self) -> Log:
        """Measured channels plus the TRUE twists (``twist12``, ``twist23``) as a CSV log."""
        chans = {c: self.y[c] for c in MEAS_CHANNELS if c in self.y}
        chans["omega_ref"] = self.action_omega_ref
        chans["twist12"] = self.state("phi12")
        chans["twist23"] = self.state("phi23")
        return Log(self.t, chans, f"closed loop: {self.controller}")


def baseline_input(scenario, t: float) -> np.ndarray:
    """Baseline (a) input at ``t``: the programme (set-point, N1, N2 = programme, normally 0)."""
    return np.asarray(scenario.input_vector(t), dtype=float)


def run_closed_loop(scenario, controller, *, estimator=None, progress=None, plant=None) -> ClosedLoopResult:
    """Run ``controller`` against the scenario's plant.

    Parameters
    ----------
    scenario : mitigate.scenario.Scenario (model "rig3")
    controller : mitigate.controllers.base.Controller
    estimator : estimators.base.StateEstimator, or None to build ``scenario.estimator``
        with the NOMINAL ``scenario.model_params``
    progress : optional callable ``progress(k_done)`` called every 100 samples
    plant : optional pre-built plant (tests); default: ``models.plant.Plant`` with
        ``scenario.plant_params``, sensors, servo and sim options

    Returns
    -------
    ClosedLoopResult
    """
    if scenario.model != "rig3":
        raise ConfigError(f"{scenario.path or 'scenario'}: scenario.model must be 'rig3' for a closed loop, "
                          f"got {scenario.model!r}")
    model = get_model("rig3")
    dt = scenario.dt
    n = int(round(scenario.duration / dt))
    if n < 1:
        raise ConfigError(f"scenario.duration must be at least one sample ({dt} s), got {scenario.duration}")
    u0 = baseline_input(scenario, 0.0)
    if plant is None:
        plant = Plant(model, scenario.plant_params, scenario.sim, sensors=scenario.sensors, servo=scenario.servo,
                      u0=u0)
    if estimator is None:
        # the estimator's initial guess comes from the NOMINAL model, never from the plant
        x0 = (model.steady_sliding(u0, scenario.model_params) if scenario.sim.start == "sliding"
              else np.zeros(model.nx))
        estimator = make_estimator(scenario.estimator, scenario.model_params, scenario.sensors, dt, x0=x0,
                                   where=f"{scenario.path or 'scenario'}: estimator")
    controller.reset()
    k_start = int(math.ceil(scenario.control_start / dt - 1e-9))
    every = scenario.control_every

    T = np.arange(n + 1) * dt
    X = np.full((n + 1, model.nx), np.nan)
    U = np.full((n + 1, model.nu), np.nan)
    A_n2 = np.full(n + 1, np.nan)
    A_w = np.full(n + 1, np.nan)
    active = np.zeros(n + 1, bool)
    ok = np.ones(n + 1, bool)
    est_times = np.full(n + 1, np.nan)
    solve_times: list[float] = []
    plan_calls: list[bool] = []
    ys: list[dict] = []
    xh: list[np.ndarray] = []
    names: tuple = ()

    y = plant.measure()
    u_prev = u0.copy()
    held = None
    status, success = "ok", True
    last = n
    X[0] = plant.x
    for k in range(n + 1):
        t = T[k]
        ys.append(y)
        # estimator input over the last sample: commanded set-point, measured pin forces
        u_est = np.array([u_prev[0], y.get("n1", u_prev[1]), y.get("n2", u_prev[2])], dtype=float)
        est = estimator.update(y, u_est, t)
        names = est.names
        xh.append(np.asarray(est.x, dtype=float))
        est_times[k] = est.solve_time
        prog = baseline_input(scenario, t)
        if k >= k_start:
            controller.set_nominal(prog[0])
            if held is None or (k - k_start) % every == 0:
                held = controller.step(t, est, y)
                solve_times.append(held.solve_time)
                plan_calls.append(not str(held.status).startswith("hold"))
            active[k] = True
            ok[k] = held.success
            u = np.array([held.omega_ref, prog[1], held.n2], dtype=float)
        else:
            u = prog
        A_w[k], A_n2[k] = u[0], u[2]
        if k == n:
            U[k] = U[k - 1] if k > 0 else u
            break
        try:
            y = plant.step(u)
            xk = np.asarray(plant.x, dtype=float)
            if not np.all(np.isfinite(xk)):
                raise FloatingPointError("non-finite plant state")
        except Exception as exc:  # the plant is the one thing that may end a run
            status, success, last = f"plant failed at t = {T[k + 1]:.3f} s: {type(exc).__name__}: {exc}", False, k
            U[k] = u
            break
        U[k] = plant.u_applied
        X[k + 1] = xk
        u_prev = u
        if progress is not None and (k + 1) % 100 == 0:
            progress(k + 1)
    m = last + 1
    keys = [c for c in MEAS_CHANNELS if c in ys[0] or c in ys[-1]]
    Y = {c: np.array([d.get(c, np.nan) for d in ys[:m]]) for c in keys}
    Y["omega_ref"] = A_w[:m].copy()
    if success and controller.counts.failures:
        status = f"ok ({controller.counts.failures} controller failure(s) answered by fallback)"
    return ClosedLoopResult(
        t=T[:m], x=X[:m], y=Y, xhat=np.array(xh[:m]), xhat_names=tuple(names), action_n2=A_n2[:m],
        action_omega_ref=A_w[:m], u=U[:m], controller_active=active[:m], controller_ok=ok[:m],
        solve_times=np.array(solve_times), plan_calls=np.array(plan_calls, dtype=bool), estimator_times=est_times[:m],
        controller_counts=controller.counts.as_dict(), estimator_counts=estimator.counts.as_dict(),
        controller=getattr(controller, "name", type(controller).__name__), states=model.states,
        inputs=model.inputs, control_start=float(k_start * dt), status=status, success=success)
