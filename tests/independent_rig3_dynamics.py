"""Dynamics of the independent rig simulator (``tests/independent_rig3.py``: the physics is
specified in that module's docstring): the pin friction law, the chain of bodies and links, its
linear modes, and the right-hand side with its analytic Jacobian.

numpy and scipy only; nothing from the project's packages.
"""

from __future__ import annotations

import math

import numpy as np

from independent_rig3_options import RigOptions


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


class ChainStructure:
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
    s = ChainStructure(opt.replace(ideal_drive=None))
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


class RigDynamics:
    """Right-hand side ``x' = f(t, x)`` of :class:`IndependentRig3` and its Jacobian (a mixin).

    It reads the rig's ``opt`` (:class:`RigOptions`), ``s`` (:class:`ChainStructure`), ``_u`` (the
    held commands ``(omega_ref, n1, n2_cmd)``), ``_n`` (the state size), ``_Jc`` (the constant part
    of the Jacobian) and ``_fast`` (from ``_make_fast_rhs``), and counts ``nfev``.
    """

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

