"""Options of the independent rig simulator (``tests/independent_rig3.py``: the physics is
specified in that module's docstring): :class:`RigOptions`, the log columns and the DAQ channels.

numpy and scipy only; nothing from the project's packages.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping, Optional, Union

#: Columns of the project's log format, in order, with their units.
LOG_COLUMNS = (
    ("t", "s"),
    ("theta1", "rad"),
    ("theta2", "rad"),
    ("theta3", "rad"),
    ("omega1", "rad/s"),
    ("omega2", "rad/s"),
    ("omega3", "rad/s"),
    ("motor_torque", "N m"),
    ("n1", "N"),
    ("n2", "N"),
    ("omega_ref", "rad/s"),
    ("twist12", "rad"),
    ("twist23", "rad"),
)

#: Measured DAQ channels (the ones a DAQ delay can apply to).
CHANNELS = ("theta1", "theta2", "theta3", "omega1", "omega2", "omega3",
            "motor_torque", "n1", "n2")


@dataclass(frozen=True)
class RigOptions:
    """All parameters of the independent rig (defaults = thesis values, SI units).

    Parameters
    ----------
    J1, J2 : float
        Disc inertias [kg m^2] (Table 3.2).
    Jm : float
        Motor rotor inertia [kg m^2] (Table 3.1); ``J3 = eta**2 Jm``.
    eta : float
        Gearbox ratio (motor speed / R3 speed).
    k1, d1, k2, d2 : float
        Shaft stiffnesses [N m/rad] (eq. 3-7) and dampings [N m s/rad] (eq. 3-9).
    L, R, KT, KE : float
        Armature inductance [H], resistance [ohm], torque constant [N m/A],
        voltage constant [V s/rad] (Table 3.1).
    Tf, Cm : float
        Motor Coulomb friction [N m] and viscous friction [N m s/rad], motor shaft.
    kp, ki : float
        Internal PI speed loop gains [V s/rad], [V/rad].
    pi_side : {"disc", "motor"}
        Speed error the PI acts on: ``w_ref - w3`` or ``eta (w_ref - w3)``.
    v_max : float or None
        Supply-voltage limit [V] (None = none), with anti-windup.
    i_max : float or None
        Armature current limit [A] (None = none).
    current_limit_gain : float
        Gain [V/A] of the drive's current-limit regulator: the voltage is
        reduced by ``gain * (|i| - i_max)`` beyond the limit (1000 V/A: the
        current exceeds ``i_max`` by ~1e-3 A per volt of excess command).
    friction_law : {"stribeck", "stribeck_viscous", "coulomb_viscous"}
        Pin friction law (see module docstring).
    mu_s, mu_k, v_s, c_v : float
        Static and kinetic coefficients (eqs. 3-11, 3-14), Stribeck speed
        [rad/s] (eq. 3-13 has 1) and viscous coefficient [s/rad].
    r1, r2 : float
        Pin radii [m]; ``r2`` is an assumption.
    v_t : float
        Regularisation speed of the sign function [rad/s].
    drift_rate : float
        Wear drift [1/s]: ``mu_s, mu_k`` times ``1 + drift_rate t``.
    servo_min, servo_max, servo_tau, servo_rate : float
        R2 servo: force saturation [N], lag [s], rate limit [N/s].
    backlash : float
        Gearbox backlash [rad, disc side]; 0 = rigid gearbox (3 bodies).
    mesh_stiffness, mesh_damping_ratio, gear_output_inertia : float
        Gear mesh used when ``backlash > 0`` [N m/rad], [-], [kg m^2].
    shaft_elements : int
        Elements per shaft section (1 = thesis model).
    shaft_diameter, shaft_length, shaft_density : float
        Steel shaft data for the element inertias [m], [m], [kg/m^3].
    ideal_drive : {None, "R3", "R2"}
        Replace the motor by a kinematic speed source at R3 or R2.
    dt : float
        DAQ sample time [s].
    ticks_per_rev : int
        Encoder resolution (R1, R2 and the motor shaft).
    torque_definition : {"reaction", "electromagnetic"}
        What the motor-torque channel measures.
    torque_noise, torque_offset, torque_gain : float
        Motor-torque channel noise std [N m], offset [N m], gain [-].
    n1_noise, n1_offset, n1_gain, n2_noise, n2_offset, n2_gain : float
        Pin load cells noise std [N], offset [N], gain [-].
    daq_delay : int or mapping
        Whole-sample delay for all channels, or ``{channel: samples}``.
    initial_condition : {"rest", "twisted", "sliding"}
        Initial state (see module docstring).
    initial_twist12, initial_twist23 : float
        Twists for ``"twisted"`` [rad].
    initial_omega, initial_n1, initial_n2 : float or None
        Speed [rad/s] and pin forces [N] at t = 0 (None = first commands).
    method : {"odepack", "Radau", "BDF", "LSODA"}
        Stiff integrator, restarted at every DAQ sample (the commands are
        piecewise constant).  "odepack": ODEPACK's LSODA through
        ``scipy.integrate.ode`` (compiled stepping loop; fastest, default);
        the others: scipy's ``solve_ivp`` solver classes (Radau IIA is the
        most robust, ~3x slower), all with the analytic Jacobian.
    rtol : float or None
        Relative tolerance (None: 1e-6 for "odepack", 1e-5 otherwise).
        Absolute tolerances: 1e-9 rad, ``1e-3 v_t`` rad/s, 1e-4 A, 1e-6 V s
        (PI state), 1e-6 N.
    """

    # mechanics
    J1: float = 0.02888
    J2: float = 0.01496
    Jm: float = 0.370e-3
    eta: float = 8.0
    k1: float = 1.1175
    d1: float = 0.02145
    k2: float = 0.3659
    d2: float = 0.01595
    # DC motor and drive
    L: float = 8.437e-4
    R: float = 0.33
    KT: float = 0.126
    KE: float = 0.0602
    Tf: float = 0.1196
    Cm: float = 1.784e-4
    kp: float = 2.8
    ki: float = 3.5
    pi_side: str = "disc"
    v_max: Optional[float] = None
    i_max: Optional[float] = None
    current_limit_gain: float = 1000.0
    # pin friction
    friction_law: str = "stribeck"
    mu_s: float = 0.5
    mu_k: float = 0.306
    v_s: float = 1.0
    c_v: float = 0.0
    r1: float = 0.047
    r2: float = 0.040
    v_t: float = 1e-4
    drift_rate: float = 0.0
    # servo on the R2 pin
    servo_min: float = 0.0
    servo_max: float = 40.0
    servo_tau: float = 0.05
    servo_rate: float = 200.0
    # structure
    backlash: float = 0.0
    mesh_stiffness: float = 200.0
    mesh_damping_ratio: float = 0.1
    gear_output_inertia: float = 2e-4
    shaft_elements: int = 1
    shaft_diameter: float = 3e-3
    shaft_length: float = 2.40
    shaft_density: float = 7850.0
    ideal_drive: Optional[str] = None
    # DAQ and sensors
    dt: float = 0.01
    ticks_per_rev: int = 1000
    torque_definition: str = "reaction"
    torque_noise: float = 0.01
    torque_offset: float = 0.0
    torque_gain: float = 1.0
    n1_noise: float = 0.2
    n1_offset: float = 0.0
    n1_gain: float = 1.0
    n2_noise: float = 0.2
    n2_offset: float = 0.0
    n2_gain: float = 1.0
    daq_delay: Union[int, Mapping[str, int]] = 0
    # initial state
    initial_condition: str = "rest"
    initial_twist12: float = 0.0
    initial_twist23: float = 0.0
    initial_omega: Optional[float] = None
    initial_n1: Optional[float] = None
    initial_n2: Optional[float] = None
    # solver
    method: str = "odepack"
    rtol: Optional[float] = None

    def replace(self, **changes) -> "RigOptions":
        """Return a copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def validate(self) -> None:
        """Raise ``ValueError`` on inconsistent options."""
        if self.pi_side not in ("disc", "motor"):
            raise ValueError("pi_side must be 'disc' or 'motor'")
        if self.friction_law not in ("stribeck", "stribeck_viscous", "coulomb_viscous"):
            raise ValueError("unknown friction_law %r" % (self.friction_law,))
        if self.torque_definition not in ("reaction", "electromagnetic"):
            raise ValueError("torque_definition must be 'reaction' or 'electromagnetic'")
        if self.ideal_drive not in (None, "R3", "R2"):
            raise ValueError("ideal_drive must be None, 'R3' or 'R2'")
        if self.ideal_drive is not None and self.backlash > 0:
            raise ValueError("backlash needs the motor (ideal_drive=None)")
        if self.initial_condition not in ("rest", "twisted", "sliding"):
            raise ValueError("initial_condition must be 'rest', 'twisted' or 'sliding'")
        if int(self.shaft_elements) != self.shaft_elements or self.shaft_elements < 1:
            raise ValueError("shaft_elements must be a positive integer")
        if self.method not in ("odepack", "Radau", "BDF", "LSODA"):
            raise ValueError("method must be odepack, Radau, BDF or LSODA")
        for ch, d in daq_delays(self).items():
            if d < 0 or int(d) != d:
                raise ValueError("daq_delay must be whole non-negative samples (%s)" % ch)



def daq_delays(opt: RigOptions) -> dict:
    """Whole-sample DAQ delay of every channel in :data:`CHANNELS` (``opt.daq_delay`` expanded)."""
    if isinstance(opt.daq_delay, Mapping):
        unknown = set(opt.daq_delay) - set(CHANNELS)
        if unknown:
            raise ValueError("unknown DAQ channels %s" % sorted(unknown))
        return {ch: int(opt.daq_delay.get(ch, 0)) for ch in CHANNELS}
    return {ch: int(opt.daq_delay) for ch in CHANNELS}
