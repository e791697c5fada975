"""Tuning of the drilling industry's stick-slip controllers from a rig file.

The industry's laws are written for a drill string, a wave guide whose characteristic
impedance is ``Z = J_p sqrt(G rho)`` (polar moment of area ``J_p``, shear modulus ``G``, density
``rho``).  A lab rig is lumped: its discs carry almost all the inertia.  The lumped analogue
follows from the same quantity written with the pipe's totals: for a uniform shaft of length
``L``, stiffness ``k = G J_p / L`` and inertia ``J = rho J_p L``, so ``Z = sqrt(k J)``.  For a rig
file, :func:`string_impedance` takes

- ``k``: the series stiffness of the springs on the path from the drive to the body whose
  stick-slip is suppressed (rig3: ``1/(1/k1 + 1/k2) = 0.276 N m/rad``), and
- ``J``: the inertia of the bodies on that path beyond the drive (rig3: ``J1 + J2 = 0.0438 kg m^2``),

so ``Z = 0.110 N m s/rad`` for rig3.  A damper of ``Z`` at the drive absorbs a torsional wave
instead of reflecting it (reflection coefficient ``(Z - c)/(Z + c)``); for one lumped mass on a
spring with a damper ``c`` at its far end, ``c = sqrt(k J)`` is also the damper that damps the
mode most.

The stick-slip frequency is near the lowest torsional mode of the chain with the boundary its
drive puts on the top (:func:`models.modal.stick_slip_frequency`, re-exported here: held by a
speed-setting drive, rig3: 0.428 Hz, its stick-slip cycle at 30 rpm and 20 N is ~2.3 s, 0.44 Hz;
free with its inertia under a torque drive).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mitigate.controllers.base import NEEDS, reading
from models.errors import ConfigError
from models.modal import stick_slip_frequency

__all__ = ["DriveTuning", "string_impedance", "stick_slip_frequency", "drive_inertia", "tuning_for",
           "absorber_frequency", "VirtualDrive"]


def _path(model, start: str, end: str) -> list:
    """Springs on the path from node ``start`` to node ``end`` (breadth-first over the spring tree)."""
    adj: dict[str, list] = {}
    for c in model.spec.connections:
        if c.stiffness is None:
            continue
        adj.setdefault(c.a, []).append((c.b, c))
        adj.setdefault(c.b, []).append((c.a, c))
    prev = {start: None}
    queue = [start]
    while queue:
        n = queue.pop(0)
        for m, c in adj.get(n, []):
            if m not in prev:
                prev[m] = (n, c)
                queue.append(m)
    if end not in prev:
        raise ConfigError(f"rig {model.name!r}: no spring path from {start!r} to {end!r}")
    out = []
    n = end
    while prev[n] is not None:
        n, c = prev[n]
        out.append(c)
    return out[::-1]


def drive_inertia(model, params) -> float:
    """The drive body's total inertia (a DC motor's ``ratio^2 Jm`` included) [kg m^2]; 0 for a speed drive."""
    if not model.drive.on_body:
        return 0.0
    return float(model.inertia(model.spec.drive.body, params.as_dict()))


def string_impedance(model, params, body: str | None = None) -> tuple[float, float, float]:
    """``(Z, k, J)``: the lumped characteristic impedance ``sqrt(k J)`` [N m s/rad] of the string from
    the drive to ``body`` (default: the rig's objective body), its series stiffness [N m/rad] and
    its inertia [kg m^2] (module docstring)."""
    body = body or model.objective_body
    start = model.spec.reference_node
    springs = _path(model, start, body)
    if not springs:
        raise ConfigError(f"rig {model.name!r}: the objective body {body!r} is the drive itself")
    P = params.as_dict()
    k = 1.0 / sum(1.0 / c.stiffness.value(P) for c in springs)
    nodes = {x for c in springs for x in (c.a, c.b)} - {start, "drive", "ground"}
    J = sum(model.inertia(b, P) for b in nodes)
    return math.sqrt(k * J), k, J


def absorber_frequency(model, params, Kp: float) -> float:
    """The tuning frequency ``f_t`` [Hz] of a SoftSpeed drive: the lowest torsional mode of the string
    with the drive acting as the law makes it at ``f_t``, a pure damper ``Kp`` (its inertia cancelled
    by the integral's spring).

    The wave that grows into stick-slip is a linear mode of the string that the friction law's
    negative damping destabilises; the law must absorb it, so it is tuned to that mode with the top
    it creates (the stick-slip limit cycle's own frequency, with its stick phase, is no property of
    the string).  Computed from the chain's matrices (:func:`models.modal.chain_matrices`) with the
    drive body massless and held by ``Kp`` (a generalised eigenproblem).  For one mass ``J`` on a
    spring ``k`` ended by a damper, ``|lambda| = sqrt(k/J)`` for any damper: the drive-held mode.
    A speed drive (no drive body) gives the drive-held mode.
    """
    import scipy.linalg
    from models.modal import chain_matrices
    body = model.spec.drive.body
    if not model.drive.on_body or body not in model.bodies:
        return stick_slip_frequency(model, params)
    M, Cd, K, _ = chain_matrices(model, params, clamped=False, damped=True)
    d = list(model.bodies).index(body)
    M, Cd = M.copy(), Cd.copy()
    M[d, d] = 0.0
    Cd[d, d] += Kp
    n = M.shape[0]
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-K, -Cd]])
    E = np.block([[np.eye(n), np.zeros((n, n))], [np.zeros((n, n)), M]])
    lam = scipy.linalg.eigvals(A, E)
    lam = lam[np.isfinite(lam)]
    osc = sorted(abs(x) for x in lam if x.imag > 1e-9 * max(1.0, abs(x)))
    if not osc:
        raise ConfigError(f"rig {model.name!r} has no torsional mode with a damper of {Kp:.4g} N m s/rad at its drive")
    return float(osc[0] / (2 * math.pi))


class VirtualDrive:
    """SoftSpeed's virtual drive ``J_v w' = Kp (w_nom - w) + I - T``, ``I' = Ki (w_nom - w)``,
    integrated EXACTLY over one control period with ``w_nom`` and ``T`` held (zero-order hold,
    ``scipy.linalg.expm``): stable for any ``J_v``, gains and period.  (The explicit Euler step it
    replaces diverges when ``Kp dt / J_v > 2``, e.g. a small geared motor's ``J_v`` at a 10 ms DAQ:
    the set-point then jumps between the ends of its band on every step.)"""

    def __init__(self, J_v: float, Kp: float, Ki: float, dt: float):
        import scipy.linalg
        A = np.array([[-Kp / J_v, 1.0 / J_v], [-Ki, 0.0]])
        B = np.array([[Kp / J_v, -1.0 / J_v], [Ki, 0.0]])
        E = scipy.linalg.expm(np.block([[A, B], [np.zeros((2, 4))]]) * dt)
        self.Ad, self.Bd = E[:2, :2], E[:2, 2:]

    def step(self, w: float, I: float, w_nom: float, T: float) -> tuple[float, float]:
        """``(w, I)`` one period later."""
        z = self.Ad @ np.array([w, I]) + self.Bd @ np.array([w_nom, T])
        return float(z[0]), float(z[1])


@dataclass(frozen=True)
class DriveTuning:
    """What the industry's tuning rules need, derived from a rig (see module docstring).

    Z [N m s/rad], k_string [N m/rad], J_string [kg m^2], J_drive [kg m^2], f_ss [Hz] (the rig's
    stick-slip frequency, :func:`models.modal.stick_slip_frequency`)
    """

    Z: float
    k_string: float
    J_string: float
    J_drive: float
    f_ss: float

    @property
    def period(self) -> float:
        """Stick-slip period ``1/f_ss`` [s]."""
        return 1.0 / self.f_ss


def tuning_for(model, params, body: str | None = None) -> DriveTuning:
    """The :class:`DriveTuning` of a rig and its (nominal) parameters."""
    Z, k, J = string_impedance(model, params, body)
    return DriveTuning(Z, k, J, drive_inertia(model, params), stick_slip_frequency(model, params))


def first_order(prev: float, x: float, dt: float, tau: float) -> float:
    """One step of a first-order low-pass with time constant ``tau`` [s] (``tau = 0``: pass through)."""
    if tau <= 0:
        return x
    a = 1.0 - math.exp(-dt / tau)
    return prev + a * (x - prev)


def drive_speed_channel(context) -> str:
    """The measured channel of the drive's speed (a DC motor's or torque drive's body, or a speed
    drive's encoder), or a one-line ConfigError."""
    m = context.model
    ch = m.speed_channel(m.drive_node)
    if ch is None:
        raise ConfigError(f"{context.where}: needs the drive's speed, which rig {m.name!r} does not measure "
                          f"(add an encoder or speed sensor on {m.drive_body or 'the drive'!r})")
    return ch


def drive_torque_channel(context) -> str:
    """The measured channel of the torque the string loads the drive with (a torque sensor at the
    drive, or a flange in the shaft at the drive: :meth:`models.rig.RigModel.drive_load_sensor`), or a
    one-line ConfigError."""
    s = context.model.drive_load_sensor()
    if s is None:
        raise ConfigError(f"{context.where}: needs {NEEDS['drive_torque']}, which rig {context.model.name!r} does not have")
    return s.channel


def np_clip(x, lo, hi):
    return float(np.clip(x, lo, hi))


class PipeTorque:
    """The torque the string loads the drive with, from the measured drive torque and speed.

    ``T_pipe = T_measured - J_inertial * dw/dt`` where the inertial term depends on what the
    torque sensor reads (README, "What the torque load cell measures"): the reaction load cell
    of a free-mounted gear motor reads ``T_pipe + ratio Jm w'``; the electromagnetic torque
    ``ratio KT i`` reads ``T_pipe + ratio^2 Jm w' + ratio (Tf + Cm ratio w)`` (the motor's own
    friction, taken from the nominal parameters); a torque drive's applied torque reads
    ``T_pipe + J_drive w'``; an inline flange in the shaft at the drive reads ``T_pipe`` itself
    (signed by the shaft's direction: :meth:`models.rig.RigModel.drive_load_sensor`).  The acceleration
    is the backward difference of the measured drive
    speed, low-passed with ``tau_acc`` [s], and the torque passes the same low-pass (matched filters:
    the part of the torque that accelerates the drive cancels exactly, also the command of a torque
    drive, whose torque channel logs it); the result is low-passed with ``tau`` [s].
    """

    def __init__(self, context, tau: float, tau_acc: float):
        m, P = context.model, context.params.as_dict()
        self.speed_ch = drive_speed_channel(context)
        self.torque_ch = drive_torque_channel(context)
        self.dt = context.period
        self.tau, self.tau_acc = tau, tau_acc
        load = m.drive_load_sensor()
        #: +1 or -1: the string's torque is ``sign * reading`` (a flange in a shaft whose second node is the drive: -1)
        self.sign = load.sign
        if load.at_drive:
            # the sensor reads T_pipe + J w' + friction(w) (models.rig.drives.Drive.pipe_torque_terms)
            self.J, self.friction = m.drive.pipe_torque_terms(m, load.sensor, P)
            #: ``(eta, Tf, Cm, eps)`` of the motor friction the torque channel includes, or None (the C core's form)
            self.motor = m.drive.pipe_torque_loss(m, load.sensor, P)
        else:           # a flange in the shaft reads the string's torque: nothing of the drive's to remove
            self.J, self.friction, self.motor = 0.0, None, None
        self.reset()

    def c_fields(self) -> dict:
        """Its values as fields of the laws' C configuration (:data:`mitigate.controllers.compiled.LAW_CONFIG`)."""
        eta, Tf, Cm, eps = self.motor or (0.0, 0.0, 0.0, 0.0)
        return dict(pipe_J=float(self.J), torque_flip=int(self.sign < 0), tau_pipe=float(self.tau), tau_acc=float(self.tau_acc),
                    motor_friction=int(self.motor is not None), eta=float(eta), Tf=float(Tf), Cm=float(Cm),
                    eps_motor=float(eps))

    def reset(self) -> None:
        self._w = None
        self._acc = 0.0
        self._T = 0.0
        self.value = None

    def update(self, measurement) -> float:
        """The new estimate [N m] from one DAQ sample (measured drive speed and torque)."""
        w = reading(measurement, self.speed_ch)
        T = self.sign * reading(measurement, self.torque_ch)
        if self._w is not None:
            self._acc = first_order(self._acc, (w - self._w) / self.dt, self.dt, self.tau_acc)
            # the torque through the SAME filter as the acceleration: LP(T) - J LP(w') = LP(T - J w'),
            # so what drives the drive's own inertia (on a torque drive: the command itself) cancels
            self._T = first_order(self._T, T, self.dt, self.tau_acc)
        else:
            self._T = T
        self._w = w
        est = self._T - self.J * self._acc - (self.friction(w) if self.friction else 0.0)
        self.value = est if self.value is None else first_order(self.value, est, self.dt, self.tau)
        return self.value
