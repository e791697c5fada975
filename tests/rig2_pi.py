"""rig2 under a PI speed loop on the motor (the seed-001 setting), as a log: one builder for the
identification tests and ``benchmarks/bench_identify.py``."""

import numpy as np

from models.logs import Log
from models.plant import Plant, SimOptions
from models.sensors import SensorOptions

#: the seed-001 disc-side speed reference [rad/s] (55 rpm at the motor through the 8:1 gearbox)
W_REF = 55 * 2 * np.pi / 60 / 8
CHANNELS = ("omega1", "omega3", "theta1", "theta3", "motor_torque")


def rig2_pi_log(true, seed: int, duration: float, *, noise_scale: float = 1.0, w_ref: float = W_REF,
                kp: float = 0.5, ki: float = 2.0) -> Log:
    """``duration`` [s] of rig2 with parameters ``true`` under ``u = kp e + ki int(e)``, ``e = w_ref -
    omega3``, sampled every 10 ms; the motor torque logged with the speeds and angles."""
    plant = Plant("rig2", true, SimOptions(seed=seed), sensors=SensorOptions(noise_scale=noise_scale))
    dt, z = plant.options.dt, 0.0
    y = plant.measure()
    rows = {c: [y[c]] for c in CHANNELS}
    t = [0.0]
    for _ in range(int(round(duration / dt))):
        e = w_ref - y["omega3"]
        z += e * dt
        y = plant.step([kp * e + ki * z])
        t.append(plant.t)
        for c in CHANNELS:
            rows[c].append(y[c])
    return Log(np.array(t), {c: np.array(v) for c, v in rows.items()}, "rig2-pi")
