"""What the NMPC's plan starts from: the servo forces, the held inputs, the rig's state and the
friction factors, from the measurements, the estimate and the NMPC's own commands.

**Servo forces.**  A servo's force comes from a replica of the rig's servo model
(:class:`models.actuators.Servo`) driven by the controller's own commands, started from the
servo's load-cell reading.  With a force window (``window_n`` > 0) the replicas' forces and the
programme of the last ``window_n`` DAQ samples are kept (:class:`.band.ForceHistory`) for the
programme's band on the moving mean (:mod:`mitigate.controllers.nmpc.band`).

**Held inputs.**  Inputs the NMPC does not set are held over the horizon: the drive at the
programme's value; a normal force at the programme's value plus the low-passed difference between
its load cell's reading (corrected for the cell's gain and offset) and the programme (time
constant ``force_filter``; a missing or non-finite reading leaves the difference as it was).  The
raw reading would pass the cell's noise to the plan: on rig3 its 0.2 N moved the set-point by
0.056 rad/s (std) at steady sliding with the TRUE state, and the programme's own steps reach the
prediction at once.

**State and disturbance model.**  The rig's state is the first ``model.nx`` entries of
``estimate.x`` (whose ``names`` must start with ``model.states``).  With ``use_load_estimate``, an
estimate state ``load:<contact>`` (the EKF's random-walk factor on a contact's friction) scales
that contact body's friction in the prediction -- the offset-free part of the design (without it a
wrong estimated twist at steady sliding left R1 15-19 % slow from rest).  In stick the friction is
a constraint force and its level unobservable: the filter's factor drifts there (rig3 from rest:
1.0 -> 2.1 in 0.5 s), so the factor is taken while the contact body slides (above
:data:`.supervision.SLIDING_FRACTION` of the nominal speed) and held while it sticks (1 before it
ever slid), clipped to :data:`LOAD_FACTOR_RANGE`.
"""

from __future__ import annotations

import math

import numpy as np

from models.actuators import Servo
from models.errors import SolverFailure
from mitigate.controllers.nmpc.band import ForceHistory
from mitigate.controllers.nmpc.supervision import SLIDING_FRACTION

__all__ = ["PlanStart", "LOAD_FACTOR_RANGE"]

#: clip of the load factor taken from an estimate (a diverging estimator must not wreck the plan)
LOAD_FACTOR_RANGE = (0.2, 5.0)


class PlanStart:
    """The plan's starting point (module docstring).

    Parameters
    ----------
    model, params : the rig the NMPC believes and its nominal parameters
    inputs : the commanded inputs (the drive's first)
    dt_daq : the DAQ period [s] (the servo replicas' step)
    force_filter : the held forces' low-pass time constant [s] (0: the raw reading)
    use_load_estimate : take ``load:<contact>`` states from the estimate
    window_n : DAQ samples of the servo forces' history (0: none kept)
    """

    def __init__(self, model, params, inputs, dt_daq: float, force_filter: float, use_load_estimate: bool,
                 window_n: int = 0):
        m = model
        self.model, self.params = m, params
        self.dt_daq, self.tau = float(dt_daq), float(force_filter)
        self.use_load_estimate = bool(use_load_estimate)
        drive = m.drive_input
        self.drives = drive in inputs
        self.servos = tuple(n for n in inputs if n != drive)
        self.acts = [m.actuator(n) for n in self.servos]
        self.held = [j for j, n in enumerate(m.inputs) if n not in inputs]
        #: ``{input index: (channel, offset, gain)}`` of the load cell measuring each non-drive input
        self.readers = {j: self._reader(n) for j, n in enumerate(m.inputs) if n != drive}
        self.load_keys = {f"load:{c}": i for i, names in enumerate(m.contact_names) for c in names}
        self.u_servo = [m.inputs.index(n) for n in self.servos]
        self.window_n = int(window_n)
        self.reset()

    def _reader(self, name: str):
        """``(channel, offset, gain)`` of the load cell that measures input ``name``, or
        ``(name, 0, 1)`` when the rig logs the input itself."""
        m, p = self.model, self.params
        contact = m.contact_of_input(name)
        for s in m.sensors:
            if s.kind == "load_cell" and contact is not None and s.target == contact.name:
                off = float(s.offset.value(p)) if s.offset is not None else 0.0
                gain = float(s.gain.value(p)) if s.gain is not None else None
                return s.channels[0], off, 1.0 if gain is None else gain
        return name, 0.0, 1.0

    def reset(self) -> None:
        self.servo_replicas = None     # replicas of the commanded servos
        #: the replicas' forces and the programme over the last window_n samples (None: not kept)
        self.history = ForceHistory(len(self.servos), self.window_n) if self.window_n > 0 else None
        self._p_last = None            # the servos' programme at the last call
        self.deviation = {}            # low-passed (reading - programme) of each held measured input
        self.friction = np.ones(len(self.model.contacts))   # the plan's friction factors
        self._names_seen = None
        self._load_idx = []

    def measured(self, j: int, measurement, fallback: float) -> float:
        """Input ``j``'s value as its load cell reads it (``fallback`` if missing or non-finite)."""
        ch, off, gain = self.readers[j]
        v = measurement.get(ch) if measurement is not None else None
        if v is None or not math.isfinite(v):
            return fallback
        return (float(v) - off) / gain

    def first_commands(self, measurement, u_prog) -> np.ndarray:
        """The commands before the first plan: the programme's set-point, the servos as measured."""
        m = self.model
        first = [float(u_prog[m.inputs.index(m.drive_input)])] if self.drives else []
        return np.array(first + [self.measured(m.inputs.index(n), measurement, u_prog[m.inputs.index(n)])
                                 for n in self.servos], float)

    def servo_forces(self, steps: int, measurement, u_prog, u_prev) -> np.ndarray:
        """The commanded servos' forces now [N]: the replicas advanced ``steps`` DAQ periods with the
        last commands ``u_prev`` (started from the load cells' readings at the first call).  Each
        step's force enters the history with the programme of the last call."""
        m = self.model
        p_now = np.array([float(u_prog[j]) for j in self.u_servo])
        if self.servo_replicas is None:
            self.servo_replicas = [Servo(a, self.dt_daq, self.measured(j, measurement, u_prog[j]))
                                   for a, j in zip(self.acts, self.u_servo)]
            if self.history is not None:
                self.history.fill([s.force for s in self.servo_replicas], p_now)
        else:
            j0 = 1 if self.drives else 0
            for _ in range(max(0, steps)):
                for i, s in enumerate(self.servo_replicas):
                    s.step(u_prev[j0 + i])
                if self.history is not None:
                    self.history.push([s.force for s in self.servo_replicas], self._p_last)
        self._p_last = p_now
        return np.array([s.force for s in self.servo_replicas])

    def held_inputs(self, elapsed: float, measurement, u_prog) -> np.ndarray:
        """The programme with every held measured input moved by its low-passed deviation
        (``elapsed``: time since the last call [s])."""
        hold = np.asarray(u_prog, float).copy()
        a = 1.0 - math.exp(-elapsed / self.tau) if self.tau > 0 else 1.0
        for j in self.held:
            if j in self.readers:
                v = self.measured(j, measurement, math.nan)
                if math.isfinite(v):
                    d = self.deviation.get(j)
                    self.deviation[j] = v - hold[j] if d is None else d + a * (v - hold[j] - d)
                hold[j] += self.deviation.get(j, 0.0)
        return hold

    def state(self, estimate, nominal: float):
        """The rig's state and the friction factors (None: the rig's) from an estimate.

        Raises
        ------
        SolverFailure : no estimate, an estimate of another rig, or a non-finite state.
        """
        if estimate is None or getattr(estimate, "x", None) is None:
            raise SolverFailure("no state estimate")
        m = self.model
        names = tuple(getattr(estimate, "names", ()) or ())
        if names is not self._names_seen:
            if names and names[:m.nx] != m.states:
                raise SolverFailure(f"the estimate's states {names[:m.nx]} are not the rig's {m.states}")
            self._load_idx = [(names.index(k), i) for k, i in self.load_keys.items() if k in names]
            self._names_seen = names
        xe = np.asarray(estimate.x, float).ravel()
        x = xe[:m.nx]
        if x.shape != (m.nx,) or not math.isfinite(x.sum()):   # a sum is finite iff every entry is
            raise SolverFailure("non-finite or short state estimate")
        if not (self.use_load_estimate and self._load_idx):
            return x, None
        fc, slide = self.friction, SLIDING_FRACTION * abs(nominal)
        for k, i in self._load_idx:
            if math.isfinite(xe[k]) and abs(x[m.contacts[i]]) > slide:
                fc[i] = min(max(float(xe[k]), LOAD_FACTOR_RANGE[0]), LOAD_FACTOR_RANGE[1])
        return x, fc
