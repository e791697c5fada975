"""Noise covariances of the 3-disc rig's estimators, derived from the sensor specification.

Measurement noise (one standard deviation, disc side of the gearbox; ``q`` is the
encoder resolution on R1/R2, ``qm = q / motor_ratio`` the motor encoder's):

=====================  =====================================================  ==================
internal measurement   variance                                               source
=====================  =====================================================  ==================
``d12 = th1 - th2``    ``2 q^2/12``  (two independent quantisation errors)     ``angle_variance``
``d23 = th2 - th3``    ``q^2/12 + qm^2/12``                                   ``angle_variance``
``d13 = th1 - th3``    ``q^2/12 + qm^2/12``                                   ``angle_variance``
``omega1``, ``omega2`` ``2 q^2/12 / dt^2``  (backward difference)              ``speed_variance``
``omega3``             ``2 qm^2/12 / dt^2``                                   ``speed_variance``
``motor_torque``       ``(torque_noise * noise_scale)^2``                      ``SensorOptions``
=====================  =====================================================  ==================

Quantisation errors are treated as white and uniform (``q^2/12``); the backward
difference makes the speed noise an MA(1) process, which the filters ignore (a known,
documented approximation).  A floor of ``1e-12`` keeps the covariances positive when
quantisation is switched off.

Process noise (per DAQ sample ``dt``) stands for what the regularised model leaves out:
an unmodelled torque of standard deviation ``q_torque`` [N m] on each disc (white over a
sample, so ``var(omega_j) = (q_torque dt / J_j)^2``), an unmodelled armature current
``q_current`` [A], and for the augmented load factors a random walk of
``q_load`` [1/sqrt(s)] (``var = q_load^2 dt``).
"""

from __future__ import annotations

import numpy as np

from models.errors import ConfigError
from models.sensors import SensorOptions

__all__ = ["measurement_variance", "process_variances", "FLOOR"]

FLOOR = 1e-12


def measurement_variance(sensors: SensorOptions, dt: float, name: str) -> float:
    """Variance of one internal measurement (see module table) [SI unit squared]."""
    qa = sensors.angle_variance()
    qm = sensors.angle_variance(motor=True)
    table = {
        "d12": 2 * qa,
        "d23": qa + qm,
        "d13": qa + qm,
        "omega1": sensors.speed_variance(dt),
        "omega2": sensors.speed_variance(dt),
        "omega3": sensors.speed_variance(dt, motor=True),
        "motor_torque": (sensors.torque_noise * sensors.noise_scale) ** 2,
    }
    if name not in table:
        raise ConfigError(f"no noise model for measurement {name!r}; expected one of {', '.join(table)}")
    return max(float(table[name]), FLOOR)


def process_variances(names, params, dt: float, *, q_torque: float, q_current: float, q_load: float,
                      q_twist: float = 0.0) -> np.ndarray:
    """Diagonal process-noise covariance per DAQ sample for the estimator states ``names``.

    Parameters
    ----------
    names : state names (rig3 states, optional "o12", "o23", "load1", "load2")
    params : Rig3Params (inertias)
    dt : DAQ period [s]
    q_torque : unmodelled torque on each disc, standard deviation [N m]
    q_current : unmodelled armature current per sample, standard deviation [A]
    q_load : random-walk intensity of the load factors [1/sqrt(s)]
    q_twist : unmodelled twist per sample, standard deviation [rad]
    """
    J = {"omega1": params.J1, "omega2": params.J2, "omega3": params.J3}
    out = []
    for n in names:
        if n in ("phi12", "phi23"):
            v = q_twist ** 2
        elif n in J:
            v = (q_torque * dt / J[n]) ** 2
        elif n == "i":
            v = q_current ** 2
        elif n == "z":
            v = 0.0   # z' = omega_ref - omega3 holds exactly (controller state)
        elif n in ("load1", "load2"):
            v = q_load ** 2 * dt
        elif n in ("o12", "o23"):
            v = 0.0   # power-on offsets are constants
        else:
            raise ConfigError(f"no process-noise model for state {n!r}")
        out.append(max(v, FLOOR))
    return np.array(out)
