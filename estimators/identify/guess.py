"""Starting values derived from the data, for fits whose published values are a poor start.

Three pieces of physics, each used where the log and the rig allow it:

1. **The stick-slip cycle** of a friction body's speed.  For one disc of inertia ``J`` on a
   spring ``k`` whose other end turns at ``Omega``, with a Coulomb drop ``Delta`` from static to
   kinetic friction (tests/test_coulomb_cycle.py verifies this exact cycle)::

       t_stick   = 2 Delta / (k Omega)
       t_slip    = (2 pi - 2 psi) / omega_n,    psi = atan(omega_n Delta / (k Omega)),  omega_n^2 = k/J
       omega_max = Omega + sqrt(Omega^2 + (omega_n Delta / k)^2)

   The measured stick time, slip time and peak speed give ``omega_n`` (so ``k`` from ``J`` or
   ``J`` from ``k``) and ``Delta/k`` (so the friction drop ``Delta``).  For a body inside a
   chain (rig3's R1) the other end is its neighbour, whose measured mean speed plays ``Omega``:
   an approximation, good enough to start from.
2. **The torque balance** behind a torque sensor.  The bodies beyond the sensor (beyond a
   connection's sensor, or all of them for a sensor at the drive) obey
   ``T_in = sum J_b w_b' + sum friction + ground damping``; with the measured speeds
   (differentiated) this gives the total friction torque, and on the sliding samples the
   friction law's levels follow by linear least squares (Stribeck: ``mu_k``, ``mu_s``; bit-rock:
   ``mu_cb``, ``mu_sb``, ``c_b``): the mean torque in sliding is the kinetic level.
3. **The twist**: where the sensor's connection (or the drive's only shaft) has encoders at both
   ends, the measured torque regressed on the angle difference and the speed difference gives
   the stiffness and damping (the encoder zero and a sensor offset go into the intercept); the
   torque passes on through every body without friction, so the next shaft's stiffness follows
   too.  Without a torque sensor, the friction body's own equation of motion on its sliding
   samples, ``J w' = s (k phi + d dw) - sgn(w) T_f``, regressed on the measured twist, relative
   speed and the law's levels (and an intercept for a free encoder zero) gives those that the
   data determine.

4. **The sawtooth of a spring's force** where no speed of the friction body is measured (a force
   sensor on the spring of a friction bench's slider): the slider is stuck until the spring's force
   reaches the static level, so the force at each slip's onset IS the static friction; an
   undamped Coulomb oscillator rebounds as far below the kinetic level as it started above it, so
   the kinetic level is the mean of the force before and after the slip (an approximation: damping
   and a speed-dependent law shorten the rebound).  Slips are events of the force
   (:func:`models.signals.slip_events`), medians over them.

Only free parameters are changed; a guess that is not finite, not positive where it must be,
or more than 100x from the starting value is dropped.  Guesses are clipped into the bounds and
``mu_k <= mu_s`` is restored.  Each guess says where it came from (:attr:`Guess.notes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimators.identify.guess_data import GuessData, N_AVG, active_contacts, far_body, far_side, stuck_threshold
from models.logs import Log
from models.params import ParameterSet
from models.rig.spec import NODE_DRIVE, NODE_GROUND
from models.signals import moving_average, stick_slip_cycles

__all__ = ["Guess", "initial_guess"]

@dataclass(frozen=True)
class Guess:
    """A data-derived starting set: ``params`` (the base set with the guessed free values),
    ``values`` ``{name: guessed value}`` and ``notes`` (one line per guess: how)."""

    params: ParameterSet
    values: dict
    notes: tuple[str, ...]


def _regress_friction(model, P, data, contacts, F, mask, free) -> dict:
    """Least squares of the summed friction magnitude ``F`` over ``contacts`` on the free levels."""
    cols: dict[str, np.ndarray] = {}
    fixed = np.zeros(int(mask.sum()))
    for c in contacts:
        ft = data.friction_terms(c)
        if ft is None:
            return {}
        terms, rest = ft
        fixed = fixed + rest[mask]
        for ref, col in terms:
            if ref.kind == "param" and ref.name in free:
                cols[ref.name] = cols.get(ref.name, 0) + col[mask]
            else:
                fixed = fixed + float(ref.value(P)) * col[mask]
    if not cols:
        return {}
    names = list(cols)
    X = np.column_stack([cols[n] for n in names])
    y = F[mask] - fixed
    out = {}
    # a level whose regressor barely varies or barely appears (static friction when every
    # sliding sample is fast) is not determined: drop it and refit
    keep = [i for i, n in enumerate(names) if np.max(np.abs(X[:, i])) > 0.05 * np.max(np.abs(X))]
    if not keep:
        return {}
    sol, *_ = np.linalg.lstsq(X[:, keep], y, rcond=None)
    for i, v in zip(keep, sol):
        out[names[i]] = float(v)
    return out


def _cycle_guess(model, P, data, body, log, free, notes, values):
    """Piece 1 (and piece 3 without a torque sensor): the stick-slip cycle of ``body``."""
    i = model.contact_bodies.index(body)
    springs = [c for c in model.spec.connections if c.stiffness is not None and body in (c.a, c.b)]
    if len(springs) != 1:
        return
    c = springs[0]
    other = c.b if c.a == body else c.a
    w_b, w_o = data.speed(body), data.speed(other)
    if w_b is None or w_o is None:
        return
    dt = data.dt
    ch = model.speed_channel(body)
    Omega = float(np.mean(w_o))
    if other in model.bodies and np.std(moving_average(w_o, N_AVG)) > 0.25 * np.std(moving_average(w_b, N_AVG)):
        return None      # the other end is a body that swings with the stick-slip: not one disc on a steady drive
    if abs(Omega) < 1e-6:
        return
    sgn = 1.0 if Omega > 0 else -1.0
    thr = stuck_threshold(model, ch, dt, Omega, N_AVG)
    ws = moving_average(sgn * w_b, N_AVG)
    cyc = stick_slip_cycles(ws, dt, thr, skip=min(1.0, 0.1 * (log.t[-1] - log.t[0])))
    if cyc is None:
        return
    Om = abs(Omega)
    wmax = float(np.mean([np.max(moving_average(sgn * w_b, 3)[a:b])
                          for a, b in zip(cyc.onsets[:-1], cyc.onsets[1:])]))
    # the N_AVG-sample average lengthens the stuck runs' edges by about N_AVG - 1 samples in all
    stick = max(cyc.stick_time - (N_AVG - 1) * dt, 0.0)
    dk = []
    slip = cyc.period - stick
    if stick >= 2 * dt:
        dk.append(stick * Om / 2)
    A = math.sqrt((wmax - Om) ** 2 - Om ** 2) if wmax - Om > Om else None
    if A is not None:
        psi = math.atan(A / Om)
    elif dk:
        # solve t_slip wn = 2 pi - 2 atan(wn dk / Omega) for wn (monotonic)
        lo, hi = 1e-3, 1e4
        for _ in range(80):
            mid = math.sqrt(lo * hi)
            lo, hi = (mid, hi) if slip * mid < 2 * math.pi - 2 * math.atan(mid * dk[0] / Om) else (lo, mid)
        psi = math.atan(math.sqrt(lo * hi) * dk[0] / Om)
    else:
        return
    wn = (2 * math.pi - 2 * psi) / slip
    if A is not None:
        dk.append(A / wn)
    dk_over_k = float(np.exp(np.mean(np.log(dk))))
    J = float(model.contact_inertia(i, np.zeros(model.nx), np.zeros(model.nu), P, 1.0))
    src = (f"stick-slip cycle of {ch} (period {cyc.period:.3g} s, stick {stick:.3g} s, peak "
           f"{wmax:.3g} rad/s, {cyc.cycles} cycles; exact Coulomb cycle)")
    kref = c.stiffness
    k = float(kref.value(P))
    if kref.kind == "param" and kref.name in free and kref.name not in values:
        k = J * wn * wn
        values[kref.name] = k
        notes.append(f"{kref.name} = {k:.4g} from the {src}")
    else:
        jref = model.spec.body(body).inertia
        if jref.kind == "param" and jref.name in free and jref.name not in values:
            Jb = float(model.inertia(body, P)) - J + k / (wn * wn)
            values[jref.name] = Jb
            notes.append(f"{jref.name} = {Jb:.4g} from the {src}")
    delta = k * dk_over_k
    return {"delta": delta, "thr": thr, "src": src, "spring": c, "other": other, "k": k}


def _sawtooth_guess(model, P, data, tq, T_in, side, free, values, notes) -> bool:
    """Piece 4: the static and kinetic levels of the one contact beyond a force sensor from the
    sawtooth of its reading ``T_in`` (the force into that side) at the slips; True if it set any."""
    from scipy.ndimage import median_filter
    from models.signals import DESPIKE, slip_events
    contacts = [c for c in model.spec.contacts if c.body in side]
    if len(side) != 1 or len(contacts) != 1 or model.speed_channel(contacts[0].body) is not None:
        return False
    ct = contacts[0]
    order = model.law(ct.name).level_order
    if order is None:
        return False
    pr = dict(ct.params)
    refs = [(pr[order[1]], "static"), (pr[order[0]], "kinetic")]
    if not any(r.kind == "param" and r.name in free and r.name not in values for r, _ in refs):
        return False
    sgn = 1.0 if np.median(T_in) >= 0 else -1.0
    y = median_filter(sgn * np.asarray(T_in, float), size=DESPIKE, mode="nearest")
    ev = slip_events(y, data.dt, "force", noise=float(tq.noise) or None)
    if ev.times.size < 2:
        return False
    on = np.round(ev.times / data.dt).astype(int)
    gap = max(int(0.25 * np.median(np.diff(on))), 2)
    peak = np.array([np.max(y[max(i - gap, 0):i + 1]) for i in on])
    after = np.array([np.min(y[i:i + gap]) for i in on])
    sc = float(np.mean(data.scale(ct)))
    if not sc > 0:
        return False
    level = {"static": float(np.median(peak)), "kinetic": float(np.median(0.5 * (peak + after)))}
    src = (f"the sawtooth of {tq.channels[0]} ({ev.times.size} slips, median period {ev.period:.3g} s: "
           f"the force at a slip's onset, and the mean of the force before and after it)")
    done = False
    for ref, role in refs:
        if ref.kind == "param" and ref.name in free and ref.name not in values:
            values[ref.name] = level[role] / sc
            notes.append(f"{ref.name} = {values[ref.name]:.4g}, the {role} level from {src}")
            done = True
    return done


def _walk_chain(model, P, data, conn, T_conn, free, values, notes, source):
    """Stiffness and damping of ``conn`` (and onward along the chain) from its torque ``T_conn``
    (its reading convention, ``k phi + d (w_a - w_b)``) regressed on the encoder twist; the torque
    passes on through every body without friction that joins exactly two springs."""
    active = {c.body for c in active_contacts(model, data, model.spec.contacts)}
    c, Tc = conn, T_conn
    for _ in range(len(model.spec.connections)):
        tha, thb = data.angle(c.a), data.angle(c.b)
        wa, wb = data.speed(c.a), data.speed(c.b)
        if tha is not None and thb is not None and wa is not None and wb is not None:
            X = np.column_stack([tha - thb, moving_average(wa - wb, 3), np.ones_like(Tc)])
            (kk, dd, _), *_ = np.linalg.lstsq(X, Tc, rcond=None)
            for ref, v, what in ((c.stiffness, kk, "stiffness"), (c.damping, dd, "damping")):
                if ref is not None and ref.kind == "param" and ref.name in free and ref.name not in values and v > 0:
                    values[ref.name] = float(v)
                    P[ref.name] = float(v)
                    notes.append(f"{ref.name} = {v:.4g} from {source} regressed on the encoder twist of {c.name} ({what})")
        b = far_body(model, c)
        if b is None or b in active or data.speed(b) is None:
            return
        others = [o for o in model.spec.connections if o is not c and b in (o.a, o.b) and NODE_GROUND not in (o.a, o.b)]
        if len(others) != 1 or others[0].stiffness is None:
            return
        c2 = others[0]
        s, s2 = (1.0 if b == c.b else -1.0), (1.0 if b == c2.b else -1.0)
        Tb = float(model.inertia(b, P)) * data.accel(b)
        for g in model.spec.connections:          # dampers to the ground on b
            if g.damping is not None and NODE_GROUND in (g.a, g.b) and b in (g.a, g.b):
                Tb = Tb + float(g.damping.value(P)) * data.speed(b)
        c, Tc = c2, s2 * (Tb - s * Tc)
        source = f"{source} passed through {b}"


def _equation_error(model, P, data, body, free, values, notes, thr, encoder_zero):
    """The friction body's equation of motion on its sliding samples, regressed on the measured
    twists, relative speeds and friction levels (piece 3 without a torque sensor).

    ``J w' = sum_c s_c (k_c phi_c + d_c dw_c) - sgn(w) T_f(|w|)`` with the acceleration from the
    measured speed; the free stiffnesses, dampings and friction levels are the unknowns, plus one
    intercept for the encoder zeros when they are free (``k z``).  A coefficient is used only if the
    regression determines it (relative standard error below 30 %)."""
    conns = [c for c in model.spec.connections if body in (c.a, c.b)]
    y = float(model.inertia(body, P)) * data.accel(body)
    w = data.speed(body)
    cols: dict[str, np.ndarray] = {}
    for c in conns:
        o = c.b if c.a == body else c.a
        s = 1.0 if body == c.b else -1.0
        if o == NODE_GROUND:
            if c.damping is not None:
                y = y + float(c.damping.value(P)) * w       # (fixed) damper to the ground
            continue
        tha, thb, wa, wb = data.angle(c.a), data.angle(c.b), data.speed(c.a), data.speed(c.b)
        if tha is None or thb is None or wa is None or wb is None:
            return
        for ref, reg in ((c.stiffness, s * (tha - thb)), (c.damping, s * moving_average(wa - wb, 3))):
            if ref is None:
                continue
            if ref.kind == "param" and ref.name in free and ref.name not in values:
                cols[ref.name] = cols.get(ref.name, 0) + reg
            else:
                y = y - float(ref.value(P)) * reg
        if encoder_zero == "free" and c.stiffness is not None:
            cols["(encoder zero)"] = cols.get("(encoder zero)", 0) + s * np.ones_like(w)
    sg = np.sign(w)
    no_use: set[str] = set()      # static levels: barely seen by sliding samples, taken from the cycle
    for ct in model.spec.contacts:
        if ct.body != body:
            continue
        ft = data.friction_terms(ct)
        if ft is None:
            return
        terms, rest = ft
        y = y + sg * rest
        static = dict(ct.params).get(model.law(ct.name).with_role("static"))
        for ref, reg in terms:
            if ref.kind == "param" and ref.name in free and ref.name not in values:
                cols[ref.name] = cols.get(ref.name, 0) - sg * reg
                if ref is static:
                    no_use.add(ref.name)
            else:
                y = y + float(ref.value(P)) * sg * reg
    names = [n for n in cols if n != "(encoder zero)"]
    if not names:
        return
    mask = moving_average((np.abs(moving_average(w, N_AVG)) > thr).astype(float), 2 * N_AVG + 1) > 0.999
    mask[: max(5, len(mask) // 20)] = False
    if mask.sum() < 50:
        return
    allnames = list(cols)
    X = np.column_stack([np.broadcast_to(cols[n], w.shape)[mask] for n in allnames])
    yy = y[mask]
    scale = np.maximum(np.sqrt(np.mean(X * X, axis=0)), 1e-300)
    sol, *_ = np.linalg.lstsq(X / scale, yy, rcond=None)
    resid = yy - (X / scale) @ sol
    s2 = float(resid @ resid) / max(len(yy) - len(allnames), 1)
    try:
        cov = s2 * np.linalg.inv((X / scale).T @ (X / scale))
    except np.linalg.LinAlgError:
        return
    coef = sol / scale
    se = np.sqrt(np.maximum(np.diag(cov), 0)) / scale
    for n, v, e in zip(allnames, coef, se):
        if n == "(encoder zero)" or n in no_use or not (v > 0 and e < 0.3 * v):
            continue
        values[n] = float(v)
        P[n] = float(v)
        notes.append(f"{n} = {v:.4g} from the equation of motion of {body} on {int(mask.sum())} sliding samples "
                     f"(measured acceleration, twist and speeds; relative SE {100 * e / v:.0f} %)")


def initial_guess(model, logs, free, base: ParameterSet | None = None, *, encoder_zero: str = "free",
                  input_row: str = "end") -> Guess:
    """Data-derived values for the free parameters (see the module docstring).

    Parameters
    ----------
    model : the rig
    logs : the logs (the longest one is analysed)
    free : names of the free parameters (only these change)
    base : the set the guesses start from (default: the rig's published set)
    encoder_zero : "free" or "untwisted" (whether the twist level is known)
    input_row : the logs' row convention (unused by the estimates, which are over whole records)

    Returns
    -------
    Guess
    """
    base = model.published() if base is None else base
    logs = [logs] if isinstance(logs, Log) else list(logs)
    log = max(logs, key=lambda lg: len(lg.t))
    free = set(free)
    P = base.as_dict()
    values: dict[str, float] = {}
    notes: list[str] = []
    data = GuessData(model, log, P, input_row)
    dt = data.dt

    # the friction body: the objective body if it has friction, else the first contact body
    bodies = [b for b in model.contact_bodies if data.speed(b) is not None]
    if model.objective_body in bodies:
        bodies.remove(model.objective_body)
        bodies.insert(0, model.objective_body)

    # piece 2 and 3: a torque sensor
    tq = next((s for s in model.sensors if s.kind == "torque" and s.channels[0] in log.channels), None)
    friction_done = False
    if tq is not None:
        T_read = np.asarray(log[tq.channels[0]], float)
        T = (T_read - float(tq.offset.value(P))) / float(tq.gain.value(P)) if tq.offset is not None else T_read
        side, T_in, k_conn = None, None, None
        if tq.target == NODE_DRIVE:
            side = set(model.bodies)
            d = model.spec.drive
            wd = data.speed(d.body)
            T_in, delivered = model.drive.torque_on_body(model, tq, T, wd, None if wd is None else data.accel(d.body), P)
            # the delivered torque, for the stiffness of the drive's only shaft
            conns = [c for c in model.spec.connections if c.stiffness is not None and d.body in (c.a, c.b)]
            if delivered is not None and len(conns) == 1 and d.body not in model.contact_bodies:
                c2 = conns[0]
                k_conn = (c2, delivered if d.body == c2.a else -delivered)
        else:
            c = next(c for c in model.spec.connections if c.name == tq.target)
            side = far_side(model, c)
            T_in = T if (c.b in side) else -T
            k_conn = (c, T)
        # stiffness and damping from the connection's torque and its encoders, along the chain (piece 3)
        if k_conn is not None:
            _walk_chain(model, P, data, k_conn[0], k_conn[1], free, values, notes, tq.channels[0])
        # friction levels from the force's sawtooth at the slips where the friction body's speed is not measured (piece 4)
        if T_in is not None and side and _sawtooth_guess(model, P, data, tq, T_in, side, free, values, notes):
            friction_done = True
            P.update(values)
        # friction levels from the torque balance of the bodies beyond the sensor (piece 2)
        elif T_in is not None and side and all(data.speed(b) is not None for b in side):
            F = T_in.copy()
            for b in side:
                F = F - float(model.inertia(b, P)) * data.accel(b)
            for c in model.spec.connections:      # dampers to the ground on that side
                if c.damping is not None and NODE_GROUND in (c.a, c.b) and (c.a in side or c.b in side):
                    b = c.a if c.a in side else c.b
                    F = F - float(c.damping.value(P)) * data.speed(b)
            contacts = [c for c in model.spec.contacts if c.body in side]
            active = active_contacts(model, data, contacts)
            if active:
                wref = data.speed(active[0].body)
                sgn = 1.0 if np.mean(wref) >= 0 else -1.0
                thr = stuck_threshold(model, model.speed_channel(active[0].body) or "", dt, float(np.mean(wref))) \
                    if model.speed_channel(active[0].body) else 1e-3
                mask = np.ones(len(log.t), bool)
                for c in active:
                    w = sgn * data.speed(c.body)
                    slide = moving_average((w > thr).astype(float), 5) > 0.999   # away from transitions
                    mask &= slide
                mask[: max(5, len(mask) // 20)] = False
                if mask.sum() > 20:
                    lv = _regress_friction(model, P, data, active, sgn * F, mask, free)
                    for n, v in lv.items():
                        if n not in values:
                            values[n] = v
                            notes.append(f"{n} = {v:.4g} from the torque balance behind {tq.channels[0]} on "
                                         f"{int(mask.sum())} sliding samples")
                    friction_done = bool(lv)
                    P.update(values)
    # the friction body's equation of motion (piece 3 without a torque sensor)
    if bodies:
        b0 = bodies[0]
        ch0 = model.speed_channel(b0)
        thr0 = stuck_threshold(model, ch0, dt, float(np.mean(np.abs(data.speed(b0)))), N_AVG)
        _equation_error(model, P, data, b0, free, values, notes, thr0, encoder_zero)
    # the stick-slip cycle: stiffness (or inertia) not found above, and the friction drop
    cyc = None
    if bodies:
        cyc = _cycle_guess(model, P, data, bodies[0], log, free, notes, values)
    P.update(values)
    # the static level from the cycle's friction drop, where nothing better was found
    if cyc is not None:
        body = bodies[0]
        for ct in model.spec.contacts:
            order = model.law(ct.name).level_order
            if ct.body != body or order is None:
                continue
            pr = dict(ct.params)
            kref, sref = pr[order[0]], pr[order[1]]
            if sref.kind == "param" and sref.name in free and sref.name not in values:
                sc = float(np.mean(data.scale(ct)))
                if sc > 0:
                    v = float(kref.value(P)) + cyc["delta"] / sc
                    values[sref.name] = v
                    notes.append(f"{sref.name} = {v:.4g} = {kref.name} + the friction drop "
                                 f"{cyc['delta']:.3g} N m of the {cyc['src']}")
            break
    # sanity: finite, positive where required, within 100x of the start, inside the bounds
    out, kept = {}, []
    for n, v in values.items():
        spec = base.spec(n)
        v0 = base[n]
        lo, hi = base.bounds(n)
        if not math.isfinite(v) or (spec.positive and v <= spec.lower) or v < spec.lower:
            continue
        if v0 != 0 and not (0.01 <= abs(v / v0) <= 100):
            continue
        out[n] = float(min(max(v, lo), hi))
    for line in notes:
        if line.split(" = ")[0] in out:
            kept.append(line)
    for ct in model.spec.contacts:
        order = model.law(ct.name).level_order
        if order is not None:
            pr = dict(ct.params)
            k, s = pr[order[0]], pr[order[1]]
            if s.kind == "param" and k.kind == "param" and (s.name in out or k.name in out):
                vs, vk = out.get(s.name, base[s.name]), out.get(k.name, base[k.name])
                if vk > vs:
                    if s.name in free:
                        out[s.name] = min(vk * 1.05, base.bounds(s.name)[1])
                    elif k.name in out:
                        out[k.name] = vs
    params = base.with_vector(list(out), list(out.values())) if out else base
    return Guess(params, dict(out), tuple(kept))
