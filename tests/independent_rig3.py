"""Independent simulator of the reference 3-disc drill-string rig (thesis ch. 3).

This module is deliberately written from the physical description of the rig
alone (thesis chapter 3, Tables 3.1-3.5, eqs. 3-3, 3-7, 3-9, 3-11, 3-13,
3-14, Sect. 3.1.1) and imports nothing from the project's packages
(``models``, ``estimators``, ``mitigate``).  It is the "world we did not
write" against which identification, state estimation and controllers are
checked.  Only numpy and scipy are used.

Physical model (disc side of the 8:1 gearbox, SI units)
-------------------------------------------------------
Bodies, in chain order: disc R1 (``J1``), disc R2 (``J2``) and the motor R3,
whose rotor is reflected through the gearbox: ``J3 = eta**2 * Jm``.  Shaft
R1-R2: ``k1, d1``; shaft R2-R3: ``k2, d2`` (Kelvin-Voigt).  Angles and speeds
are positive in the driving direction (``omega_ref > 0``).

With ``theta_ij = theta_i - theta_j`` the shaft torques on the bodies are::

    J1 w1' = -k1 (th1 - th2) - d1 (w1 - w2)                        - T_r1(w1)
    J2 w2' = +k1 (th1 - th2) + d1 (w1 - w2) - k2 (th2 - th3) - d2 (w2 - w3) - T_r2(w2)
    eta**2 Jm w3' = k2 (th2 - th3) + d2 (w2 - w3) + eta (KT i - Tf sgn(wm) - Cm wm)

with ``wm = eta w3`` the motor-shaft speed.  The armature and the drive's
internal PI speed loop are::

    L i' = V - R i - KE wm,      V = kp e + ki int(e) dt
    e = w_ref - w3               (pi_side="disc", default)
    e = eta (w_ref - w3)         (pi_side="motor": PI on the motor-shaft speed error)

optionally with ``|V| <= v_max`` (conditional integration anti-windup: the
integrator is frozen while the output is saturated AND the error drives it
further into saturation) and a current limit ``|i| <= i_max``, modelled as
the drive's high-gain current-limit regulator: beyond the limit the voltage
command is reduced by ``current_limit_gain * (|i| - i_max)`` (1000 V/A, so the
overshoot is ~1 mA per volt of excess command; a continuous law, which a
stiff solver handles far better than a projection), the integrator being
frozen in the same way while limited.

Pin friction (thesis eq. 3-13), opposing the motion of R1 and R2::

    T_ri = N_i r_i mu(w_i) s(w_i)
    mu(w) = mu_k + (mu_s - mu_k) exp(-|w| / v_s)              "stribeck" (default)
    mu(w) = mu_k + (mu_s - mu_k) exp(-|w| / v_s) + c_v |w|    "stribeck_viscous"
    mu(w) = mu_k + c_v |w|                                    "coulomb_viscous"

where the sign function is the sharp smooth law ``s(w) = tanh(w / v_t)``,
``v_t = 1e-4`` rad/s by default, integrated by a stiff solver with an
analytic Jacobian (ODEPACK's LSODA by default, scipy's Radau IIA as an
option), restarted at every DAQ sample.  With this law a "stuck" disc creeps
at ``w = v_t atanh(T_spring / (N r mu_s))``: measured, a median 7.6e-5 rad/s
(95th percentile 1.7e-4 rad/s) during stick at N1 = 20 N, and 1e-4 to 3e-4
rad over a whole stick phase (most of it in the last tens of ms before
breakaway), i.e. < 5 % of an encoder tick (6.3e-3 rad).  Creep scales with
``v_t`` (``measure_creep`` reports it for a log).  The motor's own Coulomb
friction ``Tf`` uses the same law with ``v_t`` referred to the disc side.
Optional wear drift: ``mu_s`` and ``mu_k`` are multiplied by ``1 +
drift_rate t``.

For a pure Coulomb law with static > kinetic (e.g. the closed-form stick-slip
cycle) take a Stribeck speed much SMALLER than any sliding speed but much
larger than ``v_t`` (e.g. ``v_s = 3e-3``, ``v_t = 1e-5``): mu then drops
from mu_s to mu_k as soon as the disc slides.

Servo on the R2 pin (assumptions): the command is saturated to
``[servo_min, servo_max] = [0, 40] N``, followed by a first-order lag
``tau = 50 ms`` whose rate is limited to ``200 N/s``.  ``N1`` is an input.

The motor-torque load cell (Sect. 3.1.1 and RIG-FACTS.md)
---------------------------------------------------------
The ENGEL GNM 5480-G6.1 is a gear motor: DC motor and 8:1 planetary gearbox
share one housing, which is mounted on two bearings and held against rotation
by the load cell.  Take as the free body the whole floating assembly
(housing + stator + rotor + gear train + output flange).  The torques that
cross its boundary about the common (coaxial) axis are only

* ``T_lc``: the torque the load cell exerts on the housing, and
* ``T_s3 = k2 (th2 - th3) + d2 (w2 - w3)``: the torque the shaft exerts on
  the output flange (R3).

The electromagnetic torque ``KT i`` (rotor vs. stator), the motor friction
``Tf, Cm`` (rotor vs. bearings/brushes of the housing) and the tooth forces
of the planetary gear (sun/planets/ring/carrier) are all internal: they act
in equal and opposite pairs on parts of the assembly and cancel.  The
housing does not rotate; the rotor spins at ``wm = eta w3`` (same direction
for a sun-in/carrier-out planetary with a fixed ring), so the angular
momentum of the assembly is ``H = Jm eta w3`` (+ ``J_out w_out`` for an
output-flange inertia, zero in the thesis model).  Euler's law
``dH/dt = T_lc + T_s3`` gives::

    T_lc = -T_s3 + eta Jm dw3/dt = T_delivered + eta Jm dw3/dt,
    T_delivered = -(k2 (th2 - th3) + d2 (w2 - w3)),

``T_delivered`` being the torque the gearbox output delivers into the shaft
(positive when driving).  ``T_lc`` is reported with the sign that makes it
positive in steady driving.  Check by parts: rotor ``Jm wm' = KT i - Tf - Cm
wm - T_in``; massless gear train ``T_delivered = eta T_in`` so the ring takes
``(eta - 1) T_in``; housing (static) ``T_lc - (KT i - Tf - Cm wm) - (eta - 1)
T_in = 0`` hence ``T_lc = Jm wm' + eta T_in``, the same result.  It is NOT
``eta KT i`` (what a current sensor would give, ``torque_definition=
"electromagnetic"``), and not ``eta (KT i - Tf - Cm wm) = T_delivered +
eta**2 Jm w3'`` (a motor floating alone with the gearbox fixed to the frame).
In steady sliding ``T_lc = N1 r1 mu(w) + N2 r2 mu(w)`` while
``eta KT i = T_lc + eta (Tf + Cm eta w)``.

Sensors (Sect. 3.1.1), sampled by the 10 ms DAQ
-----------------------------------------------
* Incremental encoders, 1000 ticks/rev, on R1, R2 and on the MOTOR shaft
  (8000 ticks per revolution of R3).  They read 0 at power-on (t = 0) whatever
  the initial twist.  Measured angle ``floor(relative angle / tick) * tick``
  (the motor one divided by ``eta`` to give a disc-side angle, resolution
  ``2 pi / 8000``).  Speeds are backward differences of the quantised angles
  over one sample (0 at the first sample).
* Pin load cells: ``N1`` and the actual servo force ``N2``, plus Gaussian
  noise (0.2 N), with gain and offset (``meas = gain * true + offset + noise``).
* Motor-torque load cell: ``T_lc`` above (or ``eta KT i``), noise 0.01 N m,
  gain and offset.  The acceleration term is the instantaneous one at the
  sample instant.
* Optional DAQ delay of whole samples, for all channels or per channel
  (``{"motor_torque": 2, ...}``): the channel reported at ``t_k`` is the one
  sampled at ``t_{k-d}`` (the sample at ``t_0`` for ``k < d``).  The noise
  sequence does not depend on the delays, so a delayed channel is the
  undelayed one shifted by exactly ``d`` samples.

Timing / row convention
-----------------------
``reset()`` returns the measurements at ``t_0 = 0``.  ``step(cmd)`` holds the
commands over ``[t_k, t_{k+1})`` and returns the measurements sampled at
``t_{k+1}`` (an instantaneous quantity such as the load-cell reading at
``t_{k+1}`` is the left limit, i.e. it sees the inputs of the interval that
just ended; so does the ``n1`` channel: at a step of the N1 profile the
measured n1 follows one sample later).  In a log, row ``k`` holds the
measurements sampled at ``t_k``
and the commands issued at ``t_k`` (held over ``[t_k, t_{k+1})``); the
commands of the last row are recorded but not applied.  ``twist12 =
theta1 - theta2`` and ``twist23 = theta2 - theta3`` columns are the TRUE
twists at ``t_k`` (negative in steady driving: the discs lag the motor).

Structural options (all off by default)
---------------------------------------
* ``backlash`` (rad, disc side, total width of the dead zone): the rotor
  (``eta**2 Jm``) and the gearbox output flange (``gear_output_inertia``,
  2e-4 kg m^2, an assumption, about 1 % of J3) become two bodies joined by a
  mesh of stiffness ``mesh_stiffness`` = 200 N m/rad (disc side; an
  assumption: ~550x k2, so the shaft stays the compliance that matters, mesh
  mode near 160 Hz) with a dead zone, and a contact damping giving
  ``mesh_damping_ratio`` = 0.1 on the mesh mode, faded in over the first
  ``1e-4`` rad of penetration.  The drive's PI and the motor encoder see the
  rotor; the load cell reads ``T_delivered + eta Jm w_rotor' + J_out w_out'``
  (the output flange belongs to the floating assembly).  ``J_out`` is added
  to the thesis' J3; without backlash there is no separate output body.
* ``shaft_elements = n``: each shaft section becomes n elements (stiffness
  ``n k_i``, damping ``n d_i`` so that the massless limit is unchanged) with
  n - 1 interior lumped inertias.  The steel shaft (3 mm, 2.40 m, 7850 kg/m^3)
  is split between the sections in proportion to ``1/k_i`` (uniform shaft);
  its inertia ``rho pi d^4/32 L`` (1.5e-7 kg m^2 in all) is spread over the
  nodes (the end halves are added to the discs/R3).  The modes this adds are
  at kHz when undamped (n = 2: 811 and 2475 Hz; n = 3: 860, 1489, 2626,
  4548 Hz; n = 5: 886 ... 8324 Hz), but with the Kelvin-Voigt damping
  ``n d_i`` on 1e-8 kg m^2 nodes they are overdamped: real eigenvalues
  ``-k2/d2 = -22.9`` and ``-k1/d1 = -52.1`` 1/s (quasi-static relaxation of
  the nodes) and -1e6 ... -5e7 1/s (``mechanical_modes`` lists them).  Its
  effect on the logged channels is ~1e-4 N m and ~1e-4 rad of twist, i.e.
  below the sensor resolution; it mostly costs run time.
* ``daq_delay``, sensor gains and offsets: see above.
* ``ideal_drive = "R3"``: R3 moves at exactly ``omega_ref`` (clamped if 0);
  the motor is bypassed.  ``ideal_drive = "R2"``: R2 (and everything on the
  motor side of it) moves at ``omega_ref``: a single disc R1 on the spring
  ``k1`` driven at constant speed (used to check the Coulomb stick-slip
  cycle).  The torque channel then reads the torque the ideal drive delivers
  into the shaft.

Initial state
-------------
``initial_condition = "rest"`` (zero twist), ``"twisted"`` (at rest with
``initial_twist12`` and ``initial_twist23``; the motor current and PI state
are zero, as at power-on) or ``"sliding"`` (exact steady sliding at
``initial_omega`` with the pin forces ``initial_n1`` and ``initial_n2``;
``None`` takes the first commands).  In every case the servo force at t = 0
is ``initial_n2`` or, if None, the saturated first command (servo settled).
True angles are measured from R3's angle at t = 0.

Linear modes (``mechanical_modes``), thesis values: free-free undamped 0,
0.717 and 1.836 Hz; with R3 clamped 0.428 and 1.819 Hz (the thesis quotes
0.396 and 1.781 Hz measured at 30 rpm under the speed loop).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable, Mapping, Optional, Union

import numpy as np
from scipy.integrate import BDF, LSODA, Radau, ode

__all__ = [
    "RigOptions",
    "IndependentRig3",
    "simulate_log",
    "write_csv",
    "mechanical_modes",
    "measure_creep",
    "friction_coefficient",
    "LOG_COLUMNS",
    "CHANNELS",
]

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

Profile = Union[float, Callable[[float], float], np.ndarray]


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
        for ch, d in _delays(self).items():
            if d < 0 or int(d) != d:
                raise ValueError("daq_delay must be whole non-negative samples (%s)" % ch)


def _delays(opt: RigOptions) -> dict:
    if isinstance(opt.daq_delay, Mapping):
        unknown = set(opt.daq_delay) - set(CHANNELS)
        if unknown:
            raise ValueError("unknown DAQ channels %s" % sorted(unknown))
        return {ch: int(opt.daq_delay.get(ch, 0)) for ch in CHANNELS}
    return {ch: int(opt.daq_delay) for ch in CHANNELS}


def friction_coefficient(opt: RigOptions, w, t: float = 0.0):
    """Friction coefficient ``mu(w)`` of the chosen law (no sign), at time ``t``.

    Parameters
    ----------
    opt : RigOptions
    w : float or ndarray
        Sliding speed [rad/s].
    t : float
        Time [s] (for the wear drift).

    Returns
    -------
    float or ndarray
    """
    a = np.abs(w)
    fac = 1.0 + opt.drift_rate * t
    if opt.friction_law == "coulomb_viscous":
        return opt.mu_k * fac + opt.c_v * a
    mu = (opt.mu_k + (opt.mu_s - opt.mu_k) * np.exp(-a / opt.v_s)) * fac
    if opt.friction_law == "stribeck_viscous":
        mu = mu + opt.c_v * a
    return mu


class _Structure:
    """Bodies and linear links of the chain for a set of options."""

    def __init__(self, opt: RigOptions):
        n = int(opt.shaft_elements)
        eta = opt.eta
        J3 = eta ** 2 * opt.Jm
        Jp = math.pi * opt.shaft_diameter ** 4 / 32.0
        c1, c2 = 1.0 / opt.k1, 1.0 / opt.k2
        L1 = opt.shaft_length * c1 / (c1 + c2)
        L2 = opt.shaft_length * c2 / (c1 + c2)
        Js1 = opt.shaft_density * Jp * L1
        Js2 = opt.shaft_density * Jp * L2
        self.section_lengths = (L1, L2)
        self.section_inertias = (Js1, Js2)
        J = [opt.J1]
        links = []  # (a, b, k, d)
        for sec, (k, d, Js) in enumerate(((opt.k1, opt.d1, Js1), (opt.k2, opt.d2, Js2))):
            a = len(J) - 1
            if n > 1:
                J[a] += Js / (2 * n)
            for e in range(n - 1):
                J.append(Js / n)
                links.append((len(J) - 2, len(J) - 1, n * k, n * d))
            J.append(opt.J2 if sec == 0 else J3)
            if n > 1:
                J[-1] += Js / (2 * n)
            links.append((len(J) - 2, len(J) - 1, n * k, n * d))
        self.i1 = 0
        self.i2 = n
        self.i3 = 2 * n          # gearbox output (= rotor when no backlash)
        self.backlash = opt.backlash > 0
        if self.backlash:
            # R3 splits: output flange at i3, rotor appended.
            J[self.i3] -= J3
            J[self.i3] += opt.gear_output_inertia
            J.append(J3)
            jr, jo = J3, J[self.i3]
            jeff = jr * jo / (jr + jo)
            self.k_mesh = opt.mesh_stiffness
            self.c_mesh = 2.0 * opt.mesh_damping_ratio * math.sqrt(opt.mesh_stiffness * jeff)
            self.half_gap = 0.5 * opt.backlash
            self.mesh_fade = 1e-4
        self.irot = len(J) - 1
        self.J = np.array(J, dtype=float)
        nb = len(J)
        self.nb = nb
        K = np.zeros((nb, nb))
        D = np.zeros((nb, nb))
        for a, b, k, d in links:
            K[a, a] += k; K[b, b] += k; K[a, b] -= k; K[b, a] -= k
            D[a, a] += d; D[b, b] += d; D[a, b] -= d; D[b, a] -= d
        self.K, self.D = K, D
        self.links = links
        # the link delivering torque into the shaft at R3 (last linear link)
        self.link3 = links[-1]
        kin = np.zeros(nb, dtype=bool)
        if opt.ideal_drive == "R3":
            kin[self.i3:] = True
        elif opt.ideal_drive == "R2":
            kin[self.i2:] = True
        self.kin = kin
        self.drive_body = (None if opt.ideal_drive is None else
                           (self.i3 if opt.ideal_drive == "R3" else self.i2))
        self.invJ = np.where(kin, 0.0, 1.0 / self.J)
        self.invJ_list = self.invJ.tolist()


def mechanical_modes(opt: RigOptions = RigOptions(), clamp_motor: bool = False):
    """Modes of the linear mechanical chain (no friction, no motor electrics).

    Parameters
    ----------
    opt : RigOptions
        Structure options (``shaft_elements``, ``backlash`` -> mesh stiffness).
    clamp_motor : bool
        Clamp the rotor (and the gearbox output) instead of leaving it free.

    Returns
    -------
    dict
        ``"undamped_hz"``: undamped natural frequencies [Hz] (ascending);
        ``"eigenvalues"``: eigenvalues [1/s] of the damped first-order system.
    """
    s = _Structure(opt.replace(ideal_drive=None))
    K = s.K.copy()
    D = s.D.copy()
    if s.backlash:
        a, b = s.i3, s.irot
        for (i, j, sg) in ((a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)):
            K[i, j] += sg * s.k_mesh
            D[i, j] += sg * s.c_mesh
    keep = np.arange(s.nb)
    if clamp_motor:
        keep = np.arange(s.i3)
    K = K[np.ix_(keep, keep)]
    D = D[np.ix_(keep, keep)]
    J = s.J[keep]
    Mi = np.diag(1.0 / J)
    lam = np.linalg.eigvals(Mi @ K)
    f = np.sqrt(np.clip(np.sort(lam.real), 0.0, None)) / (2 * math.pi)
    m = len(keep)
    A = np.block([[np.zeros((m, m)), np.eye(m)], [-Mi @ K, -Mi @ D]])
    ev = np.linalg.eigvals(A)
    ev = ev[np.argsort(-ev.real)]
    return {"undamped_hz": f, "eigenvalues": ev}


class IndependentRig3:
    """The 3-disc rig with its DAQ, steppable sample by sample.

    Parameters
    ----------
    options : RigOptions, optional
        Parameters (defaults = thesis values).
    seed : int or None
        Seed of the sensor noise.

    Notes
    -----
    State vector ``x = [q (nb), v (nb), i, z, N2]``: body angles and speeds
    (disc side), armature current, PI integrator state and servo force.

    Examples
    --------
    Closed loop with an external controller ``ctrl(meas) -> (w_ref, n2_cmd)``::

        rig = IndependentRig3(RigOptions(), seed=1)
        meas = rig.reset(omega_ref=3.0, n1=20.0, n2_cmd=0.0)   # t = 0
        for k in range(2000):
            w_ref, n2_cmd = ctrl(meas)                      # commands at t_k
            meas = rig.step(w_ref, 20.0, n2_cmd)            # measured at t_{k+1}
            true = rig.truth()                              # for scoring only
    """

    def __init__(self, options: RigOptions = RigOptions(), seed: Optional[int] = 0):
        options.validate()
        self.opt = options
        self.seed = seed
        self.s = _Structure(options)
        self._delay = _delays(options)
        self._solver_cls = {"Radau": Radau, "BDF": BDF, "LSODA": LSODA,
                            "odepack": None}[options.method]
        self._rtol = (options.rtol if options.rtol is not None else
                      (1e-6 if options.method == "odepack" else 1e-5))
        nb = self.s.nb
        self._n = 2 * nb + 3
        self._atol = np.concatenate([np.full(nb, 1e-9), np.full(nb, 1e-3 * options.v_t),
                                     [1e-4, 1e-6, 1e-6]])
        self._tick = 2 * math.pi / options.ticks_per_rev
        # constant part of the Jacobian
        Jc = np.zeros((self._n, self._n))
        Jc[:nb, nb:2 * nb] = np.eye(nb)
        Jc[nb:2 * nb, :nb] = -self.s.invJ[:, None] * self.s.K
        Jc[nb:2 * nb, nb:2 * nb] = -self.s.invJ[:, None] * self.s.D
        self._Jc = Jc
        self._fast = self._make_fast_rhs()
        self.reset()

    # ------------------------------------------------------------------ model
    def _fric(self, w, t):
        """Return (mu(w) * tanh(w/v_t), d/dw) including the drift."""
        o = self.opt
        a = abs(w)
        sg = 1.0 if w > 0 else (-1.0 if w < 0 else 0.0)
        fac = 1.0 + o.drift_rate * t
        if o.friction_law == "coulomb_viscous":
            mu = o.mu_k * fac + o.c_v * a
            dmu = o.c_v * sg
        else:
            ex = math.exp(-a / o.v_s)
            mu = (o.mu_k + (o.mu_s - o.mu_k) * ex) * fac
            dmu = -(o.mu_s - o.mu_k) * fac * ex / o.v_s * sg
            if o.friction_law == "stribeck_viscous":
                mu += o.c_v * a
                dmu += o.c_v * sg
        th = math.tanh(w / o.v_t)
        return mu * th, dmu * th + mu * (1.0 - th * th) / o.v_t

    def _motor(self, x, wref):
        """Drive quantities: e, unsaturated V, V, saturation flag, gain g."""
        o = self.opt
        s = self.s
        nb = s.nb
        wr = x[nb + s.irot]
        z = x[2 * nb + 1]
        g = o.eta if o.pi_side == "motor" else 1.0
        e = g * (wref - wr)
        vu = o.kp * e + o.ki * z
        vc = vu
        exc = 0.0
        if o.i_max is not None:
            i = x[2 * nb]
            if i > o.i_max:
                exc = i - o.i_max
            elif i < -o.i_max:
                exc = i + o.i_max
            vc = vu - o.current_limit_gain * exc
        v = vc
        sat = False
        if o.v_max is not None and abs(vc) > o.v_max:
            v = math.copysign(o.v_max, vc)
            sat = True
        return e, vu, v, sat, g, exc

    def _rhs_jac(self, t, x, want_jac):
        o = self.opt
        s = self.s
        nb = s.nb
        wref, n1, n2c = self._u
        q = x[:nb]
        v = x[nb:2 * nb]
        n2 = x[2 * nb + 2]
        tau = -(s.K @ q) - (s.D @ v)
        jac = self._Jc.copy() if want_jac else None
        # gear mesh with backlash
        if s.backlash:
            a, b = s.i3, s.irot
            rel = q[b] - q[a]
            dw = v[b] - v[a]
            if rel > s.half_gap:
                pen, dpen = rel - s.half_gap, 1.0
            elif rel < -s.half_gap:
                pen, dpen = rel + s.half_gap, 1.0
            else:
                pen, dpen = 0.0, 0.0
            ap = abs(pen)
            if ap < s.mesh_fade:
                act = ap / s.mesh_fade
                dact = (math.copysign(1.0, pen) / s.mesh_fade) * dpen if ap > 0 else 0.0
            else:
                act, dact = 1.0, 0.0
            tm = s.k_mesh * pen + s.c_mesh * dw * act   # torque on output, -on rotor
            tau[a] += tm
            tau[b] -= tm
            if want_jac:
                dtm_dx = s.k_mesh * dpen + s.c_mesh * dw * dact
                dtm_dw = s.c_mesh * act
                for body, sg in ((a, 1.0), (b, -1.0)):
                    r = nb + body
                    ij = s.invJ[body] * sg
                    jac[r, b] += ij * dtm_dx
                    jac[r, a] -= ij * dtm_dx
                    jac[r, nb + b] += ij * dtm_dw
                    jac[r, nb + a] -= ij * dtm_dw
        # pin friction
        f1, df1 = self._fric(v[s.i1], t)
        f2, df2 = self._fric(v[s.i2], t)
        tau[s.i1] -= n1 * o.r1 * f1
        tau[s.i2] -= n2 * o.r2 * f2
        if want_jac:
            jac[nb + s.i1, nb + s.i1] -= s.invJ[s.i1] * n1 * o.r1 * df1
            jac[nb + s.i2, nb + s.i2] -= s.invJ[s.i2] * n2 * o.r2 * df2
            jac[nb + s.i2, 2 * nb + 2] -= s.invJ[s.i2] * o.r2 * f2
        dx = np.empty(self._n)
        dx[:nb] = v
        ii = 2 * nb
        if o.ideal_drive is None:
            i = x[ii]
            wr = v[s.irot]
            wm = o.eta * wr
            vtm = o.eta * o.v_t
            th = math.tanh(wm / vtm)
            tau[s.irot] += o.eta * (o.KT * i - o.Tf * th - o.Cm * wm)
            e, vu, vv, sat, g, exc = self._motor(x, wref)
            di = (vv - o.R * i - o.KE * wm) / o.L
            ilim = exc != 0.0
            dz = e
            if (sat and e * vv > 0) or (ilim and e * exc > 0):
                dz = 0.0
            dx[ii] = di
            dx[ii + 1] = dz
            if want_jac:
                r = nb + s.irot
                jac[r, ii] += s.invJ[s.irot] * o.eta * o.KT
                jac[r, r] -= s.invJ[s.irot] * o.eta * (o.Tf * (1 - th * th) * o.eta / vtm
                                                       + o.Cm * o.eta)
                dv_dwr = 0.0 if sat else -o.kp * g
                dv_dz = 0.0 if sat else o.ki
                dv_di = -o.current_limit_gain if (ilim and not sat) else 0.0
                jac[ii, r] = (dv_dwr - o.KE * o.eta) / o.L
                jac[ii, ii] = (dv_di - o.R) / o.L
                jac[ii, ii + 1] = dv_dz / o.L
                if dz != 0.0:
                    jac[ii + 1, r] = -g
        else:
            dx[ii] = 0.0
            dx[ii + 1] = 0.0
        dx[nb:2 * nb] = tau * s.invJ
        # servo
        target = min(max(n2c, o.servo_min), o.servo_max)
        rate = (target - n2) / o.servo_tau
        if abs(rate) > o.servo_rate:
            dx[ii + 2] = math.copysign(o.servo_rate, rate)
        else:
            dx[ii + 2] = rate
            if want_jac:
                jac[ii + 2, ii + 2] = -1.0 / o.servo_tau
        return dx, jac, tau

    def _fun(self, t, x):
        """Right-hand side (the hot path; the same function as ``_rhs_jac``)."""
        self.nfev += 1
        return self._fast(t, x, self._u)

    def _make_fast_rhs(self):
        """Build the right-hand side as a closure over plain floats (speed)."""
        o = self.opt
        s = self.s
        nb = s.nb
        links = tuple(s.links)
        i1, i2, i3, irot = s.i1, s.i2, s.i3, s.irot
        invJ = tuple(s.invJ.tolist())
        rng_nb = range(nb)
        backlash = s.backlash
        half_gap = s.half_gap if backlash else 0.0
        k_mesh = s.k_mesh if backlash else 0.0
        c_mesh = s.c_mesh if backlash else 0.0
        fade = s.mesh_fade if backlash else 1.0
        r1, r2 = o.r1, o.r2
        law = o.friction_law
        mu_s, mu_k, v_s, c_v, v_t, drift = o.mu_s, o.mu_k, o.v_s, o.c_v, o.v_t, o.drift_rate
        motor = o.ideal_drive is None
        eta, KT, Tf, Cm, R, L, KE = o.eta, o.KT, o.Tf, o.Cm, o.R, o.L, o.KE
        kp, ki = o.kp, o.ki
        g = eta if o.pi_side == "motor" else 1.0
        v_max = o.v_max
        i_max = o.i_max
        gcl = o.current_limit_gain
        smin, smax, stau, srate = o.servo_min, o.servo_max, o.servo_tau, o.servo_rate
        tanh, exp, copysign = math.tanh, math.exp, math.copysign
        array = np.array

        def mu_tanh(w, fac):
            a = w if w >= 0.0 else -w
            if law == "coulomb_viscous":
                mu = mu_k * fac + c_v * a
            else:
                mu = (mu_k + (mu_s - mu_k) * exp(-a / v_s)) * fac
                if law == "stribeck_viscous":
                    mu += c_v * a
            return mu * tanh(w / v_t)

        def fast(t, x, u):
            wref, n1, n2c = u
            xl = x.tolist()
            q = xl[:nb]
            v = xl[nb:2 * nb]
            tau = [0.0] * nb
            for a, b, k, d in links:
                f = k * (q[a] - q[b]) + d * (v[a] - v[b])
                tau[a] -= f
                tau[b] += f
            if backlash:
                rel = q[irot] - q[i3]
                if rel > half_gap:
                    pen = rel - half_gap
                elif rel < -half_gap:
                    pen = rel + half_gap
                else:
                    pen = 0.0
                act = min(abs(pen) / fade, 1.0)
                tm = k_mesh * pen + c_mesh * (v[irot] - v[i3]) * act
                tau[i3] += tm
                tau[irot] -= tm
            fac = 1.0 + drift * t
            n2 = xl[2 * nb + 2]
            tau[i1] -= n1 * r1 * mu_tanh(v[i1], fac)
            tau[i2] -= n2 * r2 * mu_tanh(v[i2], fac)
            if motor:
                i = xl[2 * nb]
                z = xl[2 * nb + 1]
                wr = v[irot]
                wm = eta * wr
                tau[irot] += eta * (KT * i - Tf * tanh(wr / v_t) - Cm * wm)
                e = g * (wref - wr)
                vc = kp * e + ki * z
                exc = 0.0
                if i_max is not None:
                    if i > i_max:
                        exc = i - i_max
                    elif i < -i_max:
                        exc = i + i_max
                    vc -= gcl * exc
                sat = False
                if v_max is not None and abs(vc) > v_max:
                    vc = copysign(v_max, vc)
                    sat = True
                di = (vc - R * i - KE * wm) / L
                dz = 0.0 if ((sat and e * vc > 0) or (exc != 0.0 and e * exc > 0)) else e
            else:
                di = dz = 0.0
            target = min(max(n2c, smin), smax)
            rate = (target - n2) / stau
            if abs(rate) > srate:
                rate = copysign(srate, rate)
            return array(v + [tau[j] * invJ[j] for j in rng_nb] + [di, dz, rate])

        return fast

    def _jac(self, t, x):
        return self._rhs_jac(t, x, True)[1]

    # -------------------------------------------------------------- state I/O
    def _initial_state(self, omega_ref, n1, n2_cmd):
        o = self.opt
        s = self.s
        nb = s.nb
        x = np.zeros(self._n)
        n1_0 = o.initial_n1 if o.initial_n1 is not None else (n1 if n1 is not None else 0.0)
        if o.initial_n2 is not None:
            n2_0 = o.initial_n2
        elif n2_cmd is not None:
            n2_0 = min(max(n2_cmd, o.servo_min), o.servo_max)
        else:
            n2_0 = 0.0
        x[2 * nb + 2] = n2_0
        self._n1_prev = float(n1_0)
        if o.initial_condition == "rest":
            return x
        if o.initial_condition == "twisted":
            # linear interpolation along each section; R3 angle = 0
            q = np.zeros(nb)
            n = int(o.shaft_elements)
            th2 = o.initial_twist23
            th1 = th2 + o.initial_twist12
            for j in range(n + 1):
                q[j] = th1 - o.initial_twist12 * j / n
                q[n + j] = th2 - o.initial_twist23 * j / n
            x[:nb] = q
            return x
        # steady sliding at w0: every body at w0, twists balance the friction
        w0 = o.initial_omega if o.initial_omega is not None else (omega_ref or 0.0)
        T1 = n1_0 * o.r1 * float(friction_coefficient(o, w0)) * math.tanh(w0 / o.v_t)
        T2 = n2_0 * o.r2 * float(friction_coefficient(o, w0)) * math.tanh(w0 / o.v_t)
        n = int(o.shaft_elements)
        # torque carried by section 1 elements: T1; section 2: T1 + T2
        q = np.zeros(nb)
        # build angles backwards from the gearbox output at 0
        tw23 = -(T1 + T2) / o.k2
        tw12 = -T1 / o.k1
        th2 = tw23
        th1 = th2 + tw12
        for j in range(n + 1):
            q[j] = th1 - tw12 * j / n
            q[n + j] = th2 - tw23 * j / n
        Tdel = T1 + T2
        if s.backlash:
            # rotor ahead of output by the gap plus the mesh deflection
            q[s.irot] = s.half_gap + Tdel / s.k_mesh if Tdel >= 0 else -s.half_gap + Tdel / s.k_mesh
            q[s.irot] = q[s.i3] + q[s.irot]
        x[:nb] = q
        x[nb:2 * nb] = w0
        if o.ideal_drive is None:
            wm = o.eta * w0
            i = (Tdel / o.eta + o.Tf * math.tanh(wm / (o.eta * o.v_t)) + o.Cm * wm) / o.KT
            V = o.R * i + o.KE * wm
            x[2 * nb] = i
            x[2 * nb + 1] = V / o.ki
        return x

    def reset(self, omega_ref: Optional[float] = None, n1: Optional[float] = None,
              n2_cmd: Optional[float] = None) -> dict:
        """Power the rig on at t = 0 and return the measurements at t = 0.

        Parameters
        ----------
        omega_ref, n1, n2_cmd : float, optional
            First commands, used as the initial speed/forces when the
            corresponding ``initial_*`` options are None.

        Returns
        -------
        dict
            Measured channels (see ``step``).
        """
        self.rng = np.random.default_rng(self.seed)
        self.t = 0.0
        self.k = 0
        self._h = None
        self._ode = None
        x = self._initial_state(omega_ref, n1, n2_cmd)
        self.x = x
        self._u = (0.0 if omega_ref is None else float(omega_ref), self._n1_prev, 0.0)
        self._q0 = x[:self.s.nb].copy()
        if self.opt.ideal_drive is not None:
            self._u = (self.x[self.s.nb + self.s.drive_body], self._n1_prev, 0.0)
        self._prev_q = None
        self._hist = []
        self.nfev = 0
        return self._sample()

    def _true_torques(self):
        """True reaction and electromagnetic torques at the current state."""
        o = self.opt
        s = self.s
        nb = s.nb
        x = self.x
        dx, _, tau = self._rhs_jac(self.t, x, False)
        a, b, k, d = s.link3 if s.drive_body is None else self._drive_link()
        q = x[:nb]
        v = x[nb:2 * nb]
        if s.drive_body is None:
            # link3 joins the last shaft node (a) to the gearbox output (b).
            # The torque the flange delivers into the shaft also accelerates
            # the shaft inertia lumped on body b (shaft_elements > 1), which is
            # not part of the floating assembly.
            acc = dx[nb:2 * nb]
            own = o.gear_output_inertia if s.backlash else o.eta ** 2 * o.Jm
            t_del = k * (q[b] - q[a]) + d * (v[b] - v[a]) + (s.J[b] - own) * acc[b]
            t_react = t_del + o.Jm * o.eta * acc[s.irot]
            if s.backlash:
                t_react += o.gear_output_inertia * acc[s.i3]
            t_em = o.eta * o.KT * x[2 * nb]
        else:
            t_del = k * (q[b] - q[a]) + d * (v[b] - v[a])
            t_react = t_em = t_del
        return t_del, t_react, t_em

    def _drive_link(self):
        s = self.s
        for (a, b, k, d) in s.links:
            if b == s.drive_body:
                return a, b, k, d
        raise RuntimeError("no link into the drive body")

    def _sample(self) -> dict:
        """Sample the DAQ at the current time; return delayed channels."""
        o = self.opt
        s = self.s
        nb = s.nb
        x = self.x
        rel = x[:nb] - self._q0
        tick = self._tick
        th1 = math.floor(rel[s.i1] / tick) * tick
        th2 = math.floor(rel[s.i2] / tick) * tick
        th3 = math.floor(o.eta * rel[s.irot] / tick) * tick / o.eta
        thq = (th1, th2, th3)
        if self._prev_q is None:
            om = (0.0, 0.0, 0.0)
        else:
            om = tuple((a - b) / o.dt for a, b in zip(thq, self._prev_q))
        self._prev_q = thq
        _, t_react, t_em = self._true_torques()
        t_true = t_react if o.torque_definition == "reaction" else t_em
        noise = self.rng.standard_normal(3)
        meas = {
            "theta1": th1, "theta2": th2, "theta3": th3,
            "omega1": om[0], "omega2": om[1], "omega3": om[2],
            "motor_torque": o.torque_gain * t_true + o.torque_offset + o.torque_noise * noise[0],
            "n1": o.n1_gain * self._u[1] + o.n1_offset + o.n1_noise * noise[1],
            "n2": o.n2_gain * x[2 * nb + 2] + o.n2_offset + o.n2_noise * noise[2],
        }
        self._hist.append(meas)
        out = {"t": self.t}
        k = len(self._hist) - 1
        for ch in CHANNELS:
            out[ch] = self._hist[max(k - self._delay[ch], 0)][ch]
        return out

    # ----------------------------------------------------------------- public
    def _step_odepack(self, x, t0, t1):
        if self._ode is None:
            self._ode = ode(self._fun, self._jac)
            self._ode.set_integrator("lsoda", rtol=self._rtol, atol=self._atol,
                                     nsteps=1000000)
        r = self._ode
        r.set_initial_value(x, t0)
        y = r.integrate(t1)
        if not r.successful():
            raise RuntimeError("integration failed at t=%.4f (LSODA status %s)"
                               % (t0, r.get_return_code()))
        return np.array(y, dtype=float)

    def _step_ivp(self, x, t0, t1):
        kw = dict(rtol=self._rtol, atol=self._atol, jac=self._jac)
        if self._h is not None:
            kw["first_step"] = min(self._h, t1 - t0)
        solver = self._solver_cls(self._fun, t0, x, t1, **kw)
        hmax = 0.0
        while solver.status == "running":
            tb = solver.t
            msg = solver.step()
            if solver.status == "failed":
                raise RuntimeError("integration failed at t=%.4f: %s" % (solver.t, msg))
            h = getattr(solver, "h_abs", None)
            if solver.status == "running" and h is not None:
                hmax = max(hmax, h)      # proposal after an untruncated step
            else:
                hmax = max(hmax, solver.t - tb)
        if hmax > 0:
            # next sample starts with the step size the solver was using
            self._h = max(1.2 * hmax, 1e-7)
        return solver.y.copy()

    def step(self, omega_ref_cmd: float, n1: float, n2_cmd: float) -> dict:
        """Advance one DAQ sample with the commands held.

        Parameters
        ----------
        omega_ref_cmd : float
            Speed reference of the drive [rad/s, disc side].
        n1 : float
            Normal force on the R1 pin [N] over the interval.
        n2_cmd : float
            Servo force command for the R2 pin [N].

        Returns
        -------
        dict
            ``t`` [s] (the new sample time) and the measured channels
            ``theta1, theta2, theta3`` [rad], ``omega1, omega2, omega3``
            [rad/s], ``motor_torque`` [N m], ``n1, n2`` [N].
        """
        o = self.opt
        s = self.s
        nb = s.nb
        self._u = (float(omega_ref_cmd), float(n1), float(n2_cmd))
        x = self.x.copy()
        if o.ideal_drive is not None:
            x[nb:2 * nb][s.kin] = omega_ref_cmd
        t0 = self.t
        t1 = (self.k + 1) * o.dt
        if self._solver_cls is None:
            x1 = self._step_odepack(x, t0, t1)
        else:
            x1 = self._step_ivp(x, t0, t1)
        self.x = x1
        self.k += 1
        self.t = t1
        return self._sample()

    def truth(self) -> dict:
        """True state at the current sample time.

        Returns
        -------
        dict
            ``t``; absolute angles ``theta1, theta2, theta3`` [rad] (zero =
            R3 at t = 0; ``theta3`` is the gearbox output); speeds
            ``omega1..3``; ``twist12 = theta1 - theta2``, ``twist23 = theta2 -
            theta3``; ``theta_rotor, omega_rotor`` (disc side; equal to R3
            without backlash); ``current`` [A], ``voltage`` [V], ``pi_state``;
            ``n1, n2`` (true forces [N]); ``friction1, friction2`` [N m];
            ``torque_delivered, torque_reaction, torque_em`` [N m];
            ``shaft_nodes`` (all body angles).
        """
        o = self.opt
        s = self.s
        nb = s.nb
        x = self.x
        q = x[:nb]
        v = x[nb:2 * nb]
        t_del, t_react, t_em = self._true_torques()
        f1 = self._fric(v[s.i1], self.t)[0]
        f2 = self._fric(v[s.i2], self.t)[0]
        if o.ideal_drive is None:
            volt = self._motor(x, self._u[0])[2]
        else:
            volt = 0.0
        return {
            "t": self.t,
            "theta1": q[s.i1], "theta2": q[s.i2], "theta3": q[s.i3],
            "omega1": v[s.i1], "omega2": v[s.i2], "omega3": v[s.i3],
            "twist12": q[s.i1] - q[s.i2], "twist23": q[s.i2] - q[s.i3],
            "theta_rotor": q[s.irot], "omega_rotor": v[s.irot],
            "current": x[2 * nb], "pi_state": x[2 * nb + 1], "voltage": volt,
            "n1": self._u[1], "n2": x[2 * nb + 2],
            "friction1": self._u[1] * o.r1 * f1, "friction2": x[2 * nb + 2] * o.r2 * f2,
            "torque_delivered": t_del, "torque_reaction": t_react, "torque_em": t_em,
            "shaft_nodes": q.copy(),
        }


def _profile(p: Profile, n: int, dt: float) -> np.ndarray:
    if callable(p):
        return np.array([float(p(k * dt)) for k in range(n)])
    arr = np.asarray(p, dtype=float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if len(arr) < n:
        raise ValueError("profile array shorter than the log (%d < %d)" % (len(arr), n))
    return arr[:n].copy()


def simulate_log(options: RigOptions = RigOptions(), omega_ref_profile: Profile = math.pi,
                 n1_profile: Profile = 20.0, n2_profile: Profile = 0.0,
                 duration: float = 20.0, seed: Optional[int] = 0) -> dict:
    """Open-loop run of the rig, returned as a log (dict of arrays).

    Parameters
    ----------
    options : RigOptions
    omega_ref_profile, n1_profile, n2_profile : float, callable or array
        Commands: a constant, a function of time ``f(t_k)`` or an array with
        one value per sample.  Commands of row k are held over
        ``[t_k, t_{k+1})``.
    duration : float
        Length [s]; the log has ``round(duration/dt) + 1`` rows.
    seed : int or None
        Sensor-noise seed.

    Returns
    -------
    dict of ndarray
        The ``LOG_COLUMNS`` keys (measurements at ``t_k``, command
        ``omega_ref`` issued at ``t_k``, TRUE ``twist12``/``twist23``) plus
        ``n2_cmd``, ``n1_true``, ``n2_true``, ``omega1_true..omega3_true``,
        ``theta1_true..theta3_true``, ``current``, ``voltage``,
        ``torque_reaction_true``, ``torque_em_true``, ``omega_rotor_true``.
    """
    dt = options.dt
    n = int(round(duration / dt)) + 1
    wr = _profile(omega_ref_profile, n, dt)
    u1 = _profile(n1_profile, n, dt)
    u2 = _profile(n2_profile, n, dt)
    rig = IndependentRig3(options, seed)
    keys = [c for c, _ in LOG_COLUMNS]
    extra = ["n2_cmd", "n1_true", "n2_true", "omega1_true", "omega2_true", "omega3_true",
             "theta1_true", "theta2_true", "theta3_true", "current", "voltage",
             "torque_reaction_true", "torque_em_true", "omega_rotor_true"]
    log = {k: np.zeros(n) for k in keys + extra}
    m = rig.reset(wr[0], u1[0], u2[0])
    for k in range(n):
        tr = rig.truth()
        for ch in CHANNELS:
            log[ch][k] = m[ch]
        log["t"][k] = m["t"]
        log["omega_ref"][k] = wr[k]
        log["n2_cmd"][k] = u2[k]
        log["twist12"][k] = tr["twist12"]
        log["twist23"][k] = tr["twist23"]
        log["n1_true"][k] = tr["n1"]
        log["n2_true"][k] = tr["n2"]
        for j in (1, 2, 3):
            log["omega%d_true" % j][k] = tr["omega%d" % j]
            log["theta%d_true" % j][k] = tr["theta%d" % j]
        log["current"][k] = tr["current"]
        log["voltage"][k] = tr["voltage"]
        log["torque_reaction_true"][k] = tr["torque_reaction"]
        log["torque_em_true"][k] = tr["torque_em"]
        log["omega_rotor_true"][k] = tr["omega_rotor"]
        if k < n - 1:
            m = rig.step(wr[k], u1[k], u2[k])
    return log


def write_csv(path, log: dict, extra_columns=()) -> None:
    """Write a log in the project's CSV format.

    Parameters
    ----------
    path : str or path-like
    log : dict
        As returned by ``simulate_log``.
    extra_columns : sequence of (name, unit)
        Further columns to append after the standard ones.
    """
    cols = list(LOG_COLUMNS) + list(extra_columns)
    data = np.column_stack([np.asarray(log[c], dtype=float) for c, _ in cols])
    header = ",".join("%s [%s]" % (c, u) for c, u in cols)
    with open(path, "w", encoding="ascii") as fh:
        fh.write(header + "\n")
        for row in data:
            fh.write(",".join("%.10g" % v for v in row) + "\n")


def measure_creep(log: dict, body: int = 1, stick_speed: float = 0.01,
                  min_samples: int = 5) -> dict:
    """Creep of a disc during its stick phases, from the TRUE speeds of a log.

    Parameters
    ----------
    log : dict
        From ``simulate_log``.
    body : {1, 2}
    stick_speed : float
        A sample belongs to a stick phase when ``|omega_true| < stick_speed``.
    min_samples : int
        Shortest run of samples counted as a stick phase.

    Returns
    -------
    dict
        ``phases`` (number), ``max_speed`` [rad/s] (largest |omega| inside the
        phases, their first and last samples excluded), ``max_drift`` [rad]
        (largest angle change over a phase, same exclusion) and
        ``drift_per_second`` [rad/s] (its rate).
    """
    w = np.asarray(log["omega%d_true" % body])
    th = np.asarray(log["theta%d_true" % body])
    t = np.asarray(log["t"])
    stuck = np.abs(w) < stick_speed
    phases = []
    k = 0
    while k < len(w):
        if stuck[k]:
            j = k
            while j < len(w) and stuck[j]:
                j += 1
            if j - k >= min_samples:
                phases.append((k + 1, j - 1))   # exclude the transition samples
            k = j
        else:
            k += 1
    maxs, drift, rate = 0.0, 0.0, 0.0
    for a, b in phases:
        if b <= a:
            continue
        maxs = max(maxs, float(np.max(np.abs(w[a:b]))))
        d = abs(th[b - 1] - th[a])
        if d > drift:
            drift = d
            rate = d / max(t[b - 1] - t[a], 1e-12)
    return {"phases": len(phases), "max_speed": maxs, "max_drift": drift,
            "drift_per_second": rate}
