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

The code, by concept (all numpy and scipy; each sibling module is named ``independent_rig3_*``):
``independent_rig3_options`` (:class:`RigOptions`, ``LOG_COLUMNS``, ``CHANNELS``),
``independent_rig3_dynamics`` (``friction_coefficient``, the chain, ``mechanical_modes``, the
right-hand side and its Jacobian), ``independent_rig3_rig`` (:class:`IndependentRig3`) and
``independent_rig3_logs`` (``simulate_log``, ``write_csv``, ``measure_creep``).  Import this
module: ``import independent_rig3 as ir``.
"""

from __future__ import annotations

from independent_rig3_dynamics import friction_coefficient, mechanical_modes
from independent_rig3_logs import measure_creep, simulate_log, write_csv
from independent_rig3_options import CHANNELS, LOG_COLUMNS, RigOptions
from independent_rig3_rig import IndependentRig3

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

