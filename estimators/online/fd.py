"""Finite-difference baseline "estimator" on any rig: it reads what it can and estimates nothing.

- Twists: from the differences of consecutive encoder angles (each a combination of twists
  along the rig's spring tree, :meth:`models.rig.RigModel.angle`), solved by least squares
  for the twists they determine.  With ``angles = "zeroed"`` (incremental encoders read 0 at
  power-on) the twists of the context's ``x0`` are added: the baseline must be told the twist
  at power-on, and is off by exactly the error of that guess (0 by default: the shaft
  assumed untwisted at power-on).
- Speeds: the DAQ's speed channels (encoder backward differences, speed sensors).
- Everything else (a DC motor's current and PI integral, twists no encoder pair sees, bodies
  without a speed channel) is held at its initial value.

Covariance: the quantisation of the encoders (:func:`models.sensors.channel_variance`)
propagated through the least squares; held states keep the EKF's default prior variance.
A missing channel holds the states it would have updated.
"""

from __future__ import annotations

import numpy as np

from estimators.base import Estimate, EstimatorContext, StateEstimator
from estimators.online.channels import angle_combination, default_channels
from estimators.online.options import EKFOptions, FDOptions, for_rig
from models.errors import ConfigError
from models.rig import RigModel
from models.sensors import channel_variance
from models.status import Status

__all__ = ["FiniteDifference"]


class FiniteDifference(StateEstimator):
    """Finite-difference baseline (module docstring).

    Parameters
    ----------
    options : :class:`estimators.online.options.FDOptions`
    context : :class:`estimators.base.EstimatorContext` (its ``x0`` gives the twist at power-on)
    """

    kind = "fd"
    options_class = FDOptions

    def __init__(self, options: FDOptions, context: EstimatorContext):
        super().__init__(options, context)
        model = context.model
        if not isinstance(model, RigModel):
            raise ConfigError(f"{context.where}.model must be a RigModel, got {type(model).__name__}")
        dt = context.dt
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0:
            raise ConfigError(f"{context.where}.dt must be a finite number > 0 s, got {dt!r}")
        self.names = model.states
        chans = [c for c in default_channels(model) if model.sensor_of(c).kind in ("encoder", "speed")]
        self.channels = tuple(chans)
        nx = model.nx
        x0 = np.zeros(nx) if context.x0 is None else np.asarray(context.x0, float).ravel()[:nx]
        if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
            raise ConfigError(f"{context.where}.x0 must start with {nx} finite numbers {model.states}")
        self._x = x0.copy()
        n_tw = sum(1 for s in model.states if s.startswith("twist_"))
        angles = []
        for j, c in enumerate(chans):
            s = model.sensor_of(c)
            if s.kind == "encoder" and s.channels[0] == c:
                cv = angle_combination(model, s.target)
                if cv is not None:
                    angles.append((j, cv[:n_tw]))
        self._pairs = [(a[0], b[0]) for a, b in zip(angles[:-1], angles[1:])]
        Cm = np.array([a[1] - b[1] for a, b in zip(angles[:-1], angles[1:])]).reshape(len(self._pairs), n_tw)
        self._solve = np.linalg.pinv(Cm) if Cm.size else np.zeros((n_tw, 0))
        seen = np.abs(self._solve).sum(axis=1) > 0 if Cm.size else np.zeros(n_tw, bool)
        self._tw = np.flatnonzero(seen)
        self._tw0 = x0[:n_tw].copy() if options.angles == "zeroed" else np.zeros(n_tw)
        self._speeds = []
        for j, c in enumerate(chans):
            body = model.channel_body(c)
            if c == model.sensor_of(c).channels[-1] and body in model.bodies:
                self._speeds.append((j, model.speed_index(body)))
        # covariance: quantisation through the least squares; held states keep the default prior
        prior = for_rig(EKFOptions(), model, context.params)
        P = np.diag([prior.p0_twist ** 2] * n_tw + [prior.p0_speed ** 2] * len(model.bodies)
                    + [getattr(prior, f"p0_{s.prior}") ** 2 for s in model.drive.states])
        if self._pairs:
            T = np.zeros((len(self._pairs), len(chans)))
            for k, (a, b) in enumerate(self._pairs):
                T[k, a], T[k, b] = 1.0, -1.0
            Rr = np.diag([channel_variance(model, c, dt, context.sensors) if any(c == chans[i] for i, _ in angles)
                          else 0.0 for c in chans])
            Ptw = self._solve @ T @ Rr @ T.T @ self._solve.T
            P[np.ix_(self._tw, self._tw)] = Ptw[np.ix_(self._tw, self._tw)]
        for j, i in self._speeds:
            P[i, i] = channel_variance(model, chans[j], dt, context.sensors)
        self._P = P

    @property
    def observability_message(self) -> str:
        return "fd: estimates nothing it does not read"

    def _update_impl(self, t, y, mask, u):
        x = self._x.copy()
        if self._pairs:
            ok = all(mask[a] and mask[b] for a, b in self._pairs)
            if ok:
                d = np.array([y[a] - y[b] for a, b in self._pairs])
                x[self._tw] = (self._tw0 + self._solve @ d)[self._tw]
        for j, i in self._speeds:
            if mask[j]:
                x[i] = y[j]
        self._x = x
        msg = "ok" if mask.all() else "held: missing " + ",".join(c for c, m in zip(self.channels, mask) if not m)
        return Estimate(t, x, self._P, self.names, Status.OK, msg, bool(mask.all()))
