"""A laboratory drill string that is neither our plant nor our model: the honest stand-in for a
real lab log (SYNTHETIC, clearly labelled so wherever its log is used).

No public, redistributable, measured lab drill-string log with top and bit speeds was found
(searched: GitHub code and data repositories, lab pages, issue trackers; see
``tests/data/lab_string_stickslip.md``).  This module writes the closest honest stand-in: a
log of a string whose structure differs from every rig file we ship and from the 1-DOF models a
user would fit to it.  Like ``tests/independent_rig3.py`` it imports nothing from ``models``,
``estimators`` or ``mitigate``: numpy and scipy only.

Physics (SI units, angles positive in the drilling direction)
--------------------------------------------------------------
Bodies in chain order: the top drive (motor rotor reflected through a 5:1 gearbox, the gearbox
and the chuck: ``J_d``), ``n_pipe`` pipe nodes (slender rod lumped into equal segments, one of
them carrying a stabiliser collar), and the bottom-hole assembly with the bit (``J_b``).
Springs: a jaw coupling between the chuck and the pipe top (``k_c, d_c``) in series with the
pipe segments (``k_seg, d_seg`` each, Kelvin-Voigt), the last segment ending at the BHA.  Each
pipe node and the BHA feel a small viscous drag (``c_drag``: air and coolant).

Top drive: a digital PI speed loop at 1 kHz on the motor encoder's backward-difference speed
(quantised: 4096 counts per motor turn), one sample of computation delay, the torque clipped to
``+-T_max`` with conditional-integration anti-windup, and the gearbox's Coulomb friction
``T_gb``.  The logged top speed is therefore NOT the commanded one: it sags and surges with
every slip of the bit.

Bit-rock law (rational velocity weakening, then viscous strengthening; not in our registry)::

    T_bit = W R_b [mu_c + (mu_s - mu_c) / (1 + (|w|/v_w)^1.5)] + c_b |w|,   opposing w

with ``sign`` regularised as ``tanh(w / v_t)``, ``v_t = 1e-4`` rad/s (a stuck bit creeps far
below one encoder count per DAQ sample), integrated by LSODA restarted at every drive sample.

Weight on bit: the hydraulic feed holds ``W0`` with a slow 0.27 Hz ripple (8 %), a 3.1 Hz pump
pulsation (2 %) and a coupling to the bit speed (the depth of cut falls as the bit speeds up:
``-g_w (w_bit - w_ref)`` through a 30 ms lag); the load cell adds white noise (``wob_noise``).

DAQ: 200 Hz nominal time stamps, the encoders latched at jittered instants (Gaussian,
``jitter`` s), incremental encoders reading 0 at the first logged sample (the string is already
turning and twisted then), speeds as backward differences of the counted angles over the
nominal period; the log starts ``t_skip`` s after the drive is switched on.

Run from the repository root to (re)write the fixture::

    python tests/lab_drillstring.py [--force]
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

OUT = Path(__file__).parent / "data" / "lab_string_stickslip.csv"


@dataclass(frozen=True)
class LabString:
    """Parameters of the stand-in lab string (every value an assumption of a plausible rig)."""

    J_d: float = 0.02          # top drive, disc side of the gearbox [kg m^2]
    ratio: float = 5.0         # gearbox (motor turns per top turn)
    k_c: float = 50.0          # jaw coupling [N m/rad]
    d_c: float = 0.05          # its damping [N m s/rad]
    n_pipe: int = 6            # pipe nodes
    k_pipe: float = 7.0        # whole pipe (series of n_pipe segments) [N m/rad]
    d_seg: float = 0.01        # per segment [N m s/rad]
    J_node: float = 0.008      # each pipe node (rod with drill collars) [kg m^2]
    collar_node: int = 3       # the node carrying the stabiliser collar (1-based)
    J_collar: float = 0.03     # its extra inertia [kg m^2]
    c_drag: float = 0.002      # viscous drag per node and on the BHA [N m s/rad]
    J_b: float = 0.06          # BHA with the bit [kg m^2]
    R_b: float = 0.025         # bit radius [m]
    mu_s: float = 0.65         # bit-rock level at rest
    mu_c: float = 0.40         # bit-rock level far from rest
    v_w: float = 1.5           # weakening speed [rad/s]
    c_b: float = 0.02          # viscous strengthening [N m s/rad]
    v_t: float = 1e-4          # sign regularisation [rad/s]
    W0: float = 400.0          # weight-on-bit set-point [N]
    g_w: float = 10.0          # depth-of-cut coupling [N s/rad]
    omega_ref: float = 4.0     # top-drive set-point [rad/s]
    kp: float = 2.0            # PI [N m s/rad]
    ki: float = 20.0           # PI [N m/rad]
    T_max: float = 15.0        # drive torque limit [N m]
    T_gb: float = 0.15         # gearbox Coulomb friction [N m]
    cpr_motor: int = 4096      # motor encoder counts per motor turn
    cpr_bit: int = 10000       # BHA encoder counts per turn
    dt_drive: float = 1e-3     # drive loop period [s]
    dt_daq: float = 5e-3       # DAQ period [s]
    jitter: float = 1e-4       # DAQ sampling jitter (std) [s]
    wob_noise: float = 4.0     # load-cell noise (std) [N]
    t_skip: float = 6.0        # drive on -> first logged sample [s]
    duration: float = 12.0     # logged [s]
    seed: int = 11

    @property
    def n_bodies(self) -> int:
        return self.n_pipe + 2


def _inertias(p: LabString) -> np.ndarray:
    J = np.full(p.n_bodies, p.J_node)
    J[0], J[-1] = p.J_d, p.J_b
    J[p.collar_node] += p.J_collar
    return J


def _springs(p: LabString):
    """Stiffness and damping of the n_bodies - 1 springs in chain order (coupling+first segment in series)."""
    k_seg = p.k_pipe * p.n_pipe
    k = np.full(p.n_bodies - 1, k_seg)
    d = np.full(p.n_bodies - 1, p.d_seg)
    k[0] = 1.0 / (1.0 / p.k_c + 1.0 / k_seg)        # coupling in series with the first segment
    d[0] = 1.0 / (1.0 / p.d_c + 1.0 / p.d_seg)
    return k, d


def bit_torque(w, W, p: LabString):
    """Bit-rock torque on the BHA [N m] (opposes ``w``)."""
    a = np.abs(w)
    mag = W * p.R_b * (p.mu_c + (p.mu_s - p.mu_c) / (1.0 + (a / p.v_w) ** 1.5)) + p.c_b * a
    return -np.tanh(w / p.v_t) * mag


def _rhs(p: LabString, J, k, d):
    n = p.n_bodies

    def f(t, y, T_m, W):
        th, w = y[:n], y[n:]
        tw = th[:-1] - th[1:]
        T_s = k * tw + d * (w[:-1] - w[1:])           # torque transmitted down each spring
        acc = np.zeros(n)
        acc[:-1] -= T_s
        acc[1:] += T_s
        acc[0] += T_m - p.T_gb * math.tanh(w[0] / 1e-2)
        acc[1:] -= p.c_drag * w[1:]
        acc[-1] += bit_torque(w[-1], W, p)
        return np.concatenate([w, acc / J])

    return f


def simulate(p: LabString = LabString()):
    """Run the lab string; returns ``(t, theta_top, omega_top, theta_bit, omega_bit, wob_measured, truth)``
    at the DAQ's nominal instants (``truth``: dict of true bit speed and top torque on the pipe)."""
    rng = np.random.default_rng(p.seed)
    J = _inertias(p)
    k, d = _springs(p)
    f = _rhs(p, J, k, d)
    n = p.n_bodies
    t_end = p.t_skip + p.duration
    n_drive = int(round(t_end / p.dt_drive)) + 1
    per = int(round(p.dt_daq / p.dt_drive))
    y = np.zeros(2 * n)
    # DAQ instants (jittered), sorted and kept inside their drive step
    n_daq = int(round(p.duration / p.dt_daq)) + 1
    t_nom = p.t_skip + np.arange(n_daq) * p.dt_daq
    t_act = t_nom + np.clip(rng.normal(0.0, p.jitter, n_daq), -0.4 * p.dt_drive, 0.4 * p.dt_drive)
    th_top, th_bit, w_bit_true = np.empty(n_daq), np.empty(n_daq), np.empty(n_daq)
    W_true = np.empty(n_daq)
    j = 0
    # drive state
    q_mot = 2 * np.pi / (p.cpr_motor * p.ratio)        # one motor count, top side [rad]
    counts_prev = 0
    integ = 0.0
    T_cmd = 0.0
    W = p.W0
    tau_w = 0.03
    for i in range(n_drive):
        t0 = i * p.dt_drive
        t1 = t0 + p.dt_drive
        # weight on bit: set-point, ripple, pump pulsation, depth-of-cut coupling (first-order lag)
        W_target = p.W0 * (1 + 0.08 * math.sin(2 * math.pi * 0.27 * t0) + 0.02 * math.sin(2 * math.pi * 3.1 * t0)) \
            - p.g_w * (y[2 * n - 1] - p.omega_ref)
        W += (W_target - W) * (1 - math.exp(-p.dt_drive / tau_w))
        # the drive's PI on its own encoder, applied one sample late (computation delay)
        counts = math.floor(y[0] / q_mot)
        w_meas = (counts - counts_prev) * q_mot / p.dt_drive
        counts_prev = counts
        T_apply = T_cmd
        e = p.omega_ref - w_meas
        u = p.kp * e + p.ki * integ
        if abs(u) < p.T_max or u * e < 0:
            integ += e * p.dt_drive
        T_cmd = float(np.clip(p.kp * e + p.ki * integ, -p.T_max, p.T_max))
        ts = [tt for tt in t_act[j:j + per + 2] if t0 <= tt < t1]
        sol = solve_ivp(f, (t0, t1), y, method="LSODA", args=(T_apply, W), rtol=1e-8, atol=1e-10,
                        t_eval=ts + [t1] if ts else [t1])
        if not sol.success:
            raise RuntimeError(f"lab string: integration failed at t = {t0:.3f} s ({sol.message})")
        for c, tt in enumerate(ts):
            th_top[j], th_bit[j], w_bit_true[j] = sol.y[0, c], sol.y[n - 1, c], sol.y[2 * n - 1, c]
            W_true[j] = W
            j += 1
        y = sol.y[:, -1]
    if j != n_daq:
        raise RuntimeError(f"lab string: {j} DAQ samples taken, expected {n_daq}")
    # incremental encoders, zero at the first logged sample
    q_top, q_bit = q_mot, 2 * np.pi / p.cpr_bit
    c_top = np.floor(th_top / q_top)
    c_bit = np.floor(th_bit / q_bit)
    theta_top = (c_top - c_top[0]) * q_top
    theta_bit = (c_bit - c_bit[0]) * q_bit
    omega_top = np.r_[0.0, np.diff(theta_top)] / p.dt_daq
    omega_bit = np.r_[0.0, np.diff(theta_bit)] / p.dt_daq
    omega_top[0], omega_bit[0] = omega_top[1], omega_bit[1]
    wob = W_true + rng.normal(0.0, p.wob_noise, n_daq)
    t = np.arange(n_daq) * p.dt_daq
    return t, theta_top, omega_top, theta_bit, omega_bit, wob, {"omega_bit": w_bit_true, "wob": W_true}


def first_mode_hz(p: LabString = LabString()) -> float:
    """Lowest natural frequency [Hz] of the string with the top held and the bit free (sliding)."""
    J = _inertias(p)[1:]
    k, _ = _springs(p)
    n = len(J)
    K = np.zeros((n, n))
    for i, ki in enumerate(k):          # spring i joins body i and i+1 (body 0 held)
        a, b = i - 1, i
        if a >= 0:
            K[a, a] += ki
            K[a, b] -= ki
            K[b, a] -= ki
        K[b, b] += ki
    lam = np.linalg.eigvals(np.linalg.solve(np.diag(J), K))
    return float(np.sqrt(np.sort(lam.real))[0] / (2 * np.pi))


def csv_text(p: LabString = LabString()) -> str:
    t, tht, wt, thb, wb, wob, _ = simulate(p)
    head = ("# SYNTHETIC stand-in for a real lab drill-string log (NOT measured): tests/lab_drillstring.py, "
            f"seed {p.seed}\n"
            "# a 6-node pipe with a stabiliser collar, jaw coupling, PI top drive (1 kHz, torque limit), rational "
            "bit-rock law, hydraulic WOB; 200 Hz DAQ with jitter, quantised incremental encoders; see "
            "tests/data/lab_string_stickslip.md\n"
            "t [s],theta_top [rad],omega_top [rad/s],theta_bit [rad],omega_bit [rad/s],wob [N]\n")
    rows = "\n".join(f"{a:.3f},{b:.7g},{c:.7g},{d:.7g},{e:.7g},{g:.6g}" for a, b, c, d, e, g in
                     zip(t, tht, wt, thb, wb, wob))
    return head + rows + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Write the synthetic lab drill-string log (the stand-in for a real one).",
                                 epilog="example: python tests/lab_drillstring.py --force")
    ap.add_argument("--out", default=str(OUT), help=f"CSV to write (default {OUT})")
    ap.add_argument("--force", action="store_true", help="overwrite an existing file")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if out.exists() and not args.force:
        print(f"{out} exists (use --force)", file=sys.stderr)
        return 2
    text = csv_text()
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(out)
    print(f"wrote {out} (first mode with the top held: {first_mode_hz():.3f} Hz)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
