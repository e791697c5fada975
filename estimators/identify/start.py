"""Where a fit starts and what bounds it: parameter bounds, linear constraints, node states.

- :func:`law_bounds`: the bounds the friction laws declare for the rig parameters feeding them;
- :func:`free_bounds`: the free parameters' starting values and bounds (options', else the rig
  file's within the laws');
- :func:`constraints` / :func:`constraint_rows`: ``kinetic <= static`` per contact whose law
  declares both levels (both free) plus the options', as ``G theta <= h``, and with the bounds on
  the solver's scaled variables (:func:`scaled_constraints`);
- :func:`initial_nodes`: the shooting nodes' states from the data (measured speeds and twists, and
  what a torque sensor on a spring measures: :func:`derived_states`) and, for the rest, the EKF's
  estimates where a twist or speed is unmeasured and a torque is known (:func:`filtered_states`),
  else a smooth simulation; and the encoder zeros' starting values; :func:`state_scales`: the
  states' scales, which the continuity gaps are judged in.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.identify.options import LinearConstraint
from models.errors import ConfigError, DataError, SolverFailure
from models.friction import get_law
from models.rig.spec import NODE_DRIVE, NODE_GROUND
from models.signals import moving_average

__all__ = ["law_bounds", "free_bounds", "constraints", "constraint_rows", "scaled_constraints", "feasible",
           "initial_nodes", "filtered_states", "measured_states", "derived_states", "state_scales", "UNMEASURED_CAP",
           "SMOOTH_SAMPLES"]

#: an unmeasured speed or twist is scaled by at most this many times the largest measured one of its kind
UNMEASURED_CAP = 10.0
#: the window [samples] of the Savitzky-Golay fit (degree 2) that smooths a spring's torque into its twist
#: and differentiates it into a speed (:func:`derived_states`), after a median of :data:`SPIKE_SAMPLES`
SMOOTH_SAMPLES = 21
SPIKE_SAMPLES = 9


def law_bounds(model) -> tuple[dict, dict]:
    """Physical bounds the friction laws declare for their parameters (e.g. levels >= 0),
    ``({name: lower}, {name: upper})`` for the rig parameters that feed them."""
    lo, hi = {}, {}
    for c in model.spec.contacts:
        law = get_law(c.law)
        refs = dict(c.params)
        for prm in law.params:
            ref = refs.get(prm.name)
            if ref is None or ref.kind != "param":
                continue
            lo[ref.name] = max(lo.get(ref.name, -math.inf), prm.lower)
            hi[ref.name] = min(hi.get(ref.name, math.inf), prm.upper)
    return lo, hi


def free_bounds(model, initial, options, *, guessed: bool):
    """``(theta0, lo, hi)`` of the free parameters: ``options.bounds``, else the rig file's bounds
    within the laws' (:func:`law_bounds`).  A guessed start outside them is clipped in.

    Raises
    ------
    ConfigError : lower >= upper, or a given (not guessed) start outside its bounds
    """
    free = options.free
    theta0 = initial.vector(free)
    lo, hi = np.empty(len(free)), np.empty(len(free))
    law_lo, law_hi = law_bounds(model)
    for i, n in enumerate(free):
        b = (options.bounds or {}).get(n)
        if b is None:
            b = initial.bounds(n)
            b = (max(b[0], law_lo.get(n, -math.inf)), min(b[1], law_hi.get(n, math.inf)))
        lo[i], hi[i] = float(b[0]), float(b[1])
        if not lo[i] < hi[i]:
            raise ConfigError(f"bounds.{n} must have lower < upper, got [{lo[i]:g}, {hi[i]:g}]")
        if not lo[i] <= theta0[i] <= hi[i]:
            if guessed:
                theta0[i] = min(max(theta0[i], lo[i]), hi[i])
            else:
                raise ConfigError(f"initial {n} = {theta0[i]:g} lies outside its bounds [{lo[i]:g}, {hi[i]:g}]")
    return theta0, lo, hi


def constraints(model, options) -> tuple[LinearConstraint, ...]:
    """Bounds excluded: ``kinetic <= static`` level per contact whose law declares both (e.g. Stribeck's
    ``mu_k <= mu_s``) with both free, and the options'.

    Raises
    ------
    ConfigError : an options' constraint names an unknown parameter or no free one
    """
    m, o = model, options
    out = []
    if o.order_friction:
        seen = set()
        for c in m.spec.contacts:
            order = m.law(c.name).level_order
            if order is None:
                continue
            pr = dict(c.params)
            k, s = pr.get(order[0]), pr.get(order[1])
            if s is not None and k is not None and s.kind == k.kind == "param" and s.name in o.free \
                    and k.name in o.free and (k.name, s.name) not in seen:
                seen.add((k.name, s.name))
                out.append(LinearConstraint(((k.name, 1.0), (s.name, -1.0)), 0.0,
                                            f"{k.name} <= {s.name} (contact {c.name})"))
    for c in o.constraints:
        fixed = [n for n in c.names if n not in o.free]
        for n in fixed:
            if n not in m.param_names:
                raise ConfigError(f"options.constraints: {n!r} in {c.text!r} is not a parameter of rig {m.name!r}")
        if len(fixed) == len(c.names):
            raise ConfigError(f"options.constraints: {c.text!r} involves no free parameter "
                              f"(free: {', '.join(o.free)})")
        out.append(c)
    return tuple(out)


def constraint_rows(cons, free, initial):
    """``G theta <= h`` for the non-bound constraints (fixed parameters moved to the right-hand side)."""
    G, h = np.zeros((len(cons), len(free))), np.zeros(len(cons))
    for i, c in enumerate(cons):
        h[i] = c.upper
        for n, coef in c.terms:
            if n in free:
                G[i, free.index(n)] += coef
            else:
                h[i] -= coef * initial[n]
    return G, h


def feasible(theta, lo, hi, Gp, hp):
    """``theta`` moved onto the constraints ``Gp theta <= hp`` it violates by round-off (the
    regularised KKT rows leave ~1e-7) and clipped into the bounds ``[lo, hi]``."""
    theta = np.clip(np.asarray(theta, float), lo, hi)
    for _ in range(5):
        viol = Gp @ theta - hp if Gp.shape[0] else np.zeros(0)
        if not np.any(viol > 0):
            break
        for i in np.flatnonzero(viol > 0):
            theta = theta - Gp[i] * (viol[i] / float(Gp[i] @ Gp[i])) * (1 + 1e-12)
        theta = np.clip(theta, lo, hi)
    return theta


def scaled_constraints(sh, free, lo, hi, cons, Gp, hp):
    """All inequalities, bounds included, on the scaled border variables of the shooting problem
    ``sh``: ``(G, h, labels)`` with ``G w[:nb] <= h``; ``Gp theta <= hp`` the constraints' rows."""
    nf, nb = sh.nf, sh.nb
    rows, rhs, labels = [], [], []
    for i, n in enumerate(free):
        if np.isfinite(lo[i]):
            r = np.zeros(nb)
            r[i] = -sh.th_scale[i]
            rows.append(r)
            rhs.append(-lo[i])
            labels.append(("bound", n, "lower"))
        if np.isfinite(hi[i]):
            r = np.zeros(nb)
            r[i] = sh.th_scale[i]
            rows.append(r)
            rhs.append(hi[i])
            labels.append(("bound", n, "upper"))
    for i, c in enumerate(cons):
        r = np.zeros(nb)
        r[:nf] = Gp[i] * sh.th_scale
        rows.append(r)
        rhs.append(hp[i])
        labels.append(("constraint", c.text, ""))
    G = np.array(rows) if rows else np.zeros((0, nb))
    return G, np.array(rhs, float), labels


def measured_states(model, channels) -> tuple[dict, dict]:
    """Which states the compared channels measure directly: ``({state index: channel index}`` of the
    speeds (speed channels), ``{state index: (channel index, sign)})`` of the twists (angle
    differences across a single spring)."""
    chan_names = [c.name for c in channels]
    speed_of = {}
    for b in model.bodies:
        ch = model.speed_channel(b)
        if ch in chan_names:
            speed_of[model.speed_index(b)] = chan_names.index(ch)
    twist_of = {}
    for j, c in enumerate(channels):
        if c.kind == "twist":
            v = np.asarray(c.coefficients)
            nz = np.flatnonzero(np.abs(v) > 1e-12)
            if nz.size == 1 and abs(abs(v[nz[0]]) - 1) < 1e-12:
                twist_of[int(nz[0])] = (j, float(v[nz[0]]))
    return speed_of, twist_of


def state_scales(model, channels, nodes) -> np.ndarray:
    """(nx,) scales of the states for the solver: each state's largest magnitude over the starting
    ``nodes`` (a list of (n, nx) arrays), an unmeasured speed or twist at most :data:`UNMEASURED_CAP`
    times the largest measured one of its kind.

    The continuity gaps are judged in these units (:data:`~estimators.identify.gauss_newton.GAP_OK`),
    so a scale must be the state's size in the log: a starting simulation of an unmeasured state
    that ran off (3e5 rad/s on a field string) made a gap of 0.09 rad in an unmeasured twist count
    as closed, and the fit a confident k0 19 % off.
    """
    x_abs = np.max(np.abs(np.concatenate(nodes)), axis=0)
    scale = np.where(x_abs > 1e-6, x_abs, 1.0)
    speed_of, twist_of = measured_states(model, channels)
    speeds = [model.speed_index(b) for b in model.bodies]
    twists = list(range(len(model.springs)))
    for measured, kind in ((speed_of, speeds), (twist_of, twists)):
        if measured:
            cap = UNMEASURED_CAP * float(np.max(scale[list(measured)]))
            for j in kind:
                if j not in measured:
                    scale[j] = min(scale[j], cap)
    return np.maximum(scale, 1e-3 * np.max(scale))


def derived_states(model, channels, d, P, known: dict) -> dict:
    """``{state index: (n,) values}`` that the compared channels give through the rig's springs where
    nothing measures them directly (``known``: the measured ones, never replaced).

    A torque sensor on a spring without backlash reads ``k phi + d dw`` (gain and offset applied): its
    reading, cleared of impulsive spikes (a running median) and smoothed (Savitzky-Golay, degree 2,
    :data:`SMOOTH_SAMPLES`), over ``k`` is the twist (the damper's share neglected: a start); the
    twist's derivative then gives the speed of the spring's far end where the near end's is known (a
    speed drive's input, the ground, a measured or derived speed): ``w_b = w_a - phi'``.  A derived
    speed below three times its own noise (the reading's, estimated from the log as the median absolute
    deviation of the reading about its smoothed value, through the derivative filter) is what the log cannot
    tell from rest, and set to 0: a stuck body starts stuck.  Where a friction bench logs only its
    spring's force (a slider pulled through a spring), the nodes then follow the data; from a
    simulation at the starting values they drifted out of phase with the stick-slip at once and the fit
    never recovered (a paper-on-paper slider: cost 1.0e7 from the simulation, 1.5e5 from the data).
    """
    from scipy.signal import medfilt, savgol_filter

    n = d.Y.shape[0]
    w = min(SMOOTH_SAMPLES, n - (1 - n % 2))
    if w < 5:
        return {}
    out: dict = {}
    springs = {c.name: (j, c) for j, c in enumerate(cc for cc in model.spec.connections if cc.stiffness is not None)}
    speeds: dict = {}                       # node -> (n,) speed known: measured, the drive's, the ground's
    for b in model.bodies:
        if model.speed_index(b) in known:
            speeds[b] = np.asarray(known[model.speed_index(b)], float)
    if model.drive.sets_speed and not model.drive.on_body:      # a prescribed speed of the node "drive"
        speeds[NODE_DRIVE] = np.asarray(d.U[:, model.inputs.index(model.drive_input)], float)
    speeds[NODE_GROUND] = np.zeros(n)
    dt = float(np.median(np.diff(d.t))) if len(d.t) > 1 else 1.0
    derived = []
    for jc, ch in enumerate(channels):
        s = model.sensor_of(ch.name)
        if ch.kind != "value" or s is None or s.kind != "torque" or s.target not in springs:
            continue
        j, conn = springs[s.target]
        if j in known or conn.backlash is not None:
            continue
        k = float(conn.stiffness.value(P))
        if not (np.isfinite(k) and k > 0):
            continue
        y = (np.asarray(d.Y[:, jc], float) - float(s.offset.value(P))) / float(s.gain.value(P))
        ym = medfilt(y, SPIKE_SAMPLES)
        out[j] = savgol_filter(ym, w, 2) / k
        rate = savgol_filter(ym, w, 2, deriv=1, delta=dt) / k
        resid = y - savgol_filter(ym, w, 2)
        sigma = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
        coef = np.linalg.norm(savgol_filter(np.eye(w)[w // 2], w, 2, deriv=1, delta=dt, mode="constant")) / k
        derived.append((conn, rate, 3.0 * sigma * coef))
    for _ in range(len(derived)):                # along chains of springs, one link a pass
        for conn, rate, floor in derived:
            for near, far, sign in ((conn.a, conn.b, -1.0), (conn.b, conn.a, 1.0)):
                if near in speeds and far not in speeds and far in model.bodies:
                    v = speeds[near] + sign * rate
                    speeds[far] = np.where(np.abs(v) < floor, 0.0, v)
                    out[model.speed_index(far)] = speeds[far]
    return {i: v for i, v in out.items() if i not in known}


def initial_nodes(model, channels, data, initial, theta0, options, dt, S_val):
    """Node states from the data (measured speeds and twists) and a smooth simulation with the
    initial parameters for the unmeasured states; the encoder zeros' starting values.

    The simulation starts from steady sliding at the log's mean input, or from rest where the drive is
    commanded to stand still or every measured speed is at rest at the log's start (below 2 % of its
    largest value).

    Returns
    -------
    nodes : one (nint + 1, nx) array per log; z0 : (n_zeros,) encoder zeros; notes : what the
        start-up estimator could not do, one line per log where it failed (the simulation was used)
    """
    m, o = model, options
    M = o.shoot_every
    p0 = initial.vector()
    P0 = m.unpack(p0)
    chan_names = [c.name for c in channels]
    speed_of, twist_of = measured_states(m, channels)
    nodes_all, z0, notes = [], [], []
    for li, d in enumerate(data):
        n_used = d.nint * M + 1
        Um = np.array(m.input_from_measured([d.U[:, j] for j in range(m.nu)], P0), float).T.reshape(d.n, m.nu)
        try:
            xs = np.asarray(m.sliding_guess(np.mean(Um[:n_used], axis=0), initial), float)
            if not np.all(np.isfinite(xs)):
                raise ValueError
        except Exception:  # noqa: BLE001 - a failed solve only worsens the start
            xs = np.zeros(m.nx)
        # encoder zero guesses: the mean measured difference matches the steady-sliding twist
        zlog = {}
        for j, c in enumerate(channels):
            if c.zero:
                zlog[j] = float(np.dot(c.coefficients, xs) - np.mean(d.Y[:n_used, j]))
                z0.append(zlog[j])
        known = {}
        for idx, j in speed_of.items():
            known[idx] = moving_average(d.Y[:, j], 5)
            s = m.sensor_of(chan_names[j])
            if s is not None and s.kind == "speed":
                known[idx] = (known[idx] - float(s.offset.value(P0))) / float(s.gain.value(P0))
        for idx, (j, sgn) in twist_of.items():
            known[idx] = sgn * (moving_average(d.Y[:, j], 3) + zlog.get(j, 0.0))
        for idx, v in derived_states(m, channels, d, P0, known).items():
            known.setdefault(idx, v)
        row0 = 1 if o.input_row == "end" else 0
        # a log that starts from rest (every measured speed at its start below 2 % of its largest) starts
        # the unmeasured states from rest too, not from steady sliding: zoo example_1 (a DC-motor drive at
        # its current limit for the first 0.57 s, one encoder on the bit) started from sliding (motor at its
        # set-point, 3.1 A) took 69 iterations to a cost of 0.37; from rest 10, cost 0.040
        spd = [v for idx, v in known.items() if m.states[idx].startswith("omega_")]
        at_rest = bool(spd) and all(abs(float(v[0])) < 0.02 * max(float(np.max(np.abs(v))), 1e-300) for v in spd)
        x = xs.copy() if abs(Um[row0, m.drive_speed_index()] if m.drive_speed_index() is not None else 1.0) > 0 \
            and not at_rest else np.zeros(m.nx)
        tracked, why = filtered_states(m, d, initial, set(known), chan_names)
        if why:
            notes.append(f"start-up estimator{f' (log {li + 1})' if len(data) > 1 else ''}: {why}; the unmeasured "
                         f"states' starting nodes come from a simulation with the initial parameters instead, "
                         f"which drifts out of phase with the log's stick-slip")
        nodes = np.empty((d.nint + 1, m.nx))
        for k in range(d.nint + 1):
            if tracked is not None:
                x = tracked[min(k * M, len(tracked) - 1)].copy()
            for idx, v in known.items():
                x[idx] = v[k * M]
            nodes[k] = x
            if tracked is not None:
                continue
            if k < d.nint:
                Ub = d.U[(k * M + 1 if o.input_row == "end" else k * M):][:M]
                xn = x.copy()
                for Uk in Ub:
                    xn = np.array(S_val(xn, Uk, theta0, p0, dt, o.eps)[0]).ravel()
                x = xn if np.all(np.isfinite(xn)) and np.max(np.abs(xn)) < 1e6 else nodes[k].copy()
        nodes_all.append(nodes)
    return nodes_all, np.array(z0), tuple(notes)


def filtered_states(model, d, initial, measured: set, channels=()):
    """``(states, why)``: the rig's states along log ``d`` from the default EKF at the initial parameters
    (:func:`estimators.online.replay.estimate_log`), or None and why not ("" where the EKF is not
    meant to run: no unmeasured state, or no torque known).

    Used where the log leaves a twist or a body's speed unmeasured (a rig read at the drive only):
    a smooth simulation from the initial parameters then drifts out of phase with the log's
    stick-slip over a few cycles, and Gauss-Newton spent its 100 iterations closing the gaps (the
    student rig with the motor's encoder and torque sensor only: not converged, mu_k 0.377 +-
    0.018 against 0.32; a field-scale string on a torque drive: k0 931 +- 11 against 780).  The
    EKF believes the initial parameters (no load state), as the simulation did.

    Only where a torque is known absolutely (a compared torque channel, or a torque drive's input),
    which sets the twists' level: without one, a contact's
    friction level and the initial twist trade off (a rigid shift of the twist), the EKF's twist
    level is its prior's, and the fit ends wherever its start puts it (a 1-body speed drive read by
    its encoder's speed: mu1 -0.12 +- 0.03 from the EKF's nodes, 0.11 +- 0.64 from the
    simulation's, truth 0.3, at the same cost).  None then, when every twist and speed is
    measured, or when the EKF cannot be built on these channels or does not end ok (the
    simulation is used; ``why`` says which, and the fit reports it)."""
    mech = [i for i, s in enumerate(model.states) if s.startswith(("twist_", "omega_"))]
    if all(i in measured for i in mech):
        return None, ""
    if model.drive.sets_speed and not any(getattr(model.sensor_of(c), "kind", None) == "torque"
                                          for c in channels):
        return None, ""
    from estimators.online.replay import estimate_log
    try:
        # compiled on long logs (a 60 s log: 8.5 s of Python steps against 0.5 s compiled, once gcc has built
        # the step, ~10 s, cached); no observability checks: only the states are wanted here
        est = estimate_log(d.log, {"kind": "ekf", "compile": len(d.log.t) > 2000, "augment": [],
                                   "check_observability": False}, model, initial, observability=False)
    except (ConfigError, DataError, SolverFailure) as exc:
        return None, f"the EKF could not run ({exc})"
    x = est.x[:, :model.nx]
    if not np.all(np.isfinite(x[1:])):
        return None, "the EKF's estimate is not finite"
    if est.counts.get("failures", 0):
        return None, f"the EKF failed at {est.counts['failures']} sample(s)"
    x = x.copy()
    x[0] = x[1]                                              # row 0 is the prior
    return x, ""
