"""Local observability of an estimator's model along a trajectory: stated, not assumed.

For the discrete model of :mod:`estimators.online.model` (``x_k = F(x_{k-1}, u_k)``,
``y_k = h(x_k, u_k)``, with the chosen channels, augmented states and angle convention),
the stacked matrix over a window of ``N`` samples

    O = [C_0; C_1 A_1; C_2 A_2 A_1; ...],   A_k = dF/dx (x_{k-1}, u_k),  C_k = dh/dx (x_k, u_k)

(CasADi Jacobians) maps a perturbation of the state at the window's start to the
measurements it changes.  Each row is divided by its noise standard deviation and each
column multiplied by the state's prior standard deviation (the estimator's ``P0``), so a
singular value ``s`` says: along its right singular vector the window's measurements alone
pin the state to ``1/s`` prior standard deviations.  Two things make the test honest:

- **stick**: while a body with friction is within the regularisation speed of rest, its
  friction is a constraint force anywhere within the static limit (the regularised law's
  creep is an artefact), so every such sample adds an unknown torque on that body; these
  unknowns are eliminated (Schur complement) and inform nothing.  Without this the
  regularised creep "observes" the twist, and an EKF that trusts it converges to a wrong
  twist on an exact stick/slip plant.
- **the state that matters is the last one**: fast stable modes (a DC motor's current, a
  disc's speed under stiff friction) are invisible as *initial* conditions but forgotten
  within the window, so they do not limit the estimate.  The verdict uses the covariance of
  the window's END state, ``S^-1 Phi (O'O + w I)^-1 Phi' S^-1`` (``Phi`` the transition over
  the window; process noise and the stick torques' own uncertainty are left out).
- **the data, not the priors, must tell**: ``w = 1e-4`` gives the prior a hundredth of its
  standard deviation's weight, so an augmented state's prior (a torque offset of +-0.05 N m)
  cannot make a twist "observable" that the data leave free.

Report (:class:`ObservabilityReport`): ``singular_values``, ``rank`` and ``condition`` of the
scaled stacked matrix (initial state, stick torques eliminated), and from the end-state
covariance: the *weak directions* (information gain ``< min_gain``, default 10: the data
reduce the prior uncertainty less than tenfold), each named by its dominant states with
coefficients in prior standard deviations (``"twist_shaft2 - 0.98 zero:twist_shaft2 + 0.47
load:pin1"``); ``observable`` (no weak direction), ``twist_observable`` (every twist's
posterior standard deviation below ``1/min_gain`` of its prior), and a one-line ``message``
naming what trades off against the twist and which channel would help.

Physics worth knowing (rig3): at STEADY sliding a constant friction torque cannot be told
from a constant twist (with the encoders zeroed at power-on), nor from a constant torque-
sensor offset; ``load:pin1``, the ``zero:`` states and ``offset:motor_torque`` then trade off
exactly.  They separate only through the friction's variation with speed (stick-slip, speed
changes), which is why the estimators check both a start-up trajectory and steady sliding.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from models.errors import ConfigError
from models.status import Outcome, Status

__all__ = ["ObservabilityReport", "WeakDirection", "observability", "linearisation_function", "compress_channels", "MIN_GAIN"]

#: a direction whose information gain is below this is weak (see module docstring)
MIN_GAIN = 10.0
#: the verdicts ask what the DATA tell: the prior enters with this share of its information
#: (standard deviations 100x wider), enough to keep forgotten fast modes finite
PRIOR_WEIGHT = 1e-4


@dataclass(frozen=True)
class WeakDirection:
    """A direction of the state that the window's measurements hardly see.

    Attributes
    ----------
    singular_value : its information gain at the window's end (the data alone pin it to
        ``1/gain`` prior standard deviations; 0: not at all)
    vector : (nx,) unit vector in prior-standard-deviation units (``names`` order)
    terms : dominant states and their coefficients, largest first, the first one 1
    text : ``"twist_shaft1 + zero:twist_shaft1 - 0.71 load:pin1"``
    """

    singular_value: float
    vector: np.ndarray
    terms: tuple
    text: str


@dataclass(frozen=True)
class ObservabilityReport(Outcome):
    """Local observability along a window (module docstring).

    Attributes
    ----------
    rank : number of scaled singular values >= ``min_gain``; n : number of states
    condition : largest / smallest scaled singular value (inf if the smallest is 0)
    singular_values : (n,) singular values of the scaled stacked matrix (initial state, stick
        torques eliminated), descending
    names : estimator states; scales : (n,) prior standard deviations used as column scales
    weak : the weak directions of the END state, weakest first
    observable : no weak direction; twist_observable : every twist pinned (module docstring)
    twist_std : (n_twist,) posterior standard deviation of each twist at the end [rad]
    channels : the measured channels; samples : window length; min_gain : threshold
    regime : what the trajectory was ("start-up at the operating point", "steady sliding", ...)
    status : Status.OK, or Status.WARNING when the twist is not observable
    message : one line
    """

    rank: int
    n: int
    condition: float
    singular_values: np.ndarray
    names: tuple
    scales: np.ndarray
    weak: tuple
    observable: bool
    twist_observable: bool
    twist_std: np.ndarray
    channels: tuple
    samples: int
    min_gain: float
    status: Status = Status.OK
    message: str = ""
    twist_names: tuple = field(default=())
    regime: str = "trajectory"

    def as_dict(self) -> dict:
        """A JSON-friendly summary."""
        return {
            "observable": self.observable, "twist_observable": self.twist_observable, "rank": self.rank,
            "n": self.n, "condition": self.condition, "samples": self.samples, "min_gain": self.min_gain,
            "singular_values": self.singular_values.tolist(),
            "twist_std_rad": dict(zip(self.twist_names, self.twist_std.tolist())),
            "weak_directions": [{"gain": w.singular_value, "direction": w.text} for w in self.weak],
            "regime": self.regime, "message": self.message,
        }


def linearisation_function(em) -> ca.Function:
    """``(x_prev, x, uh, p) -> (A, C)``: ``dF/dx`` at ``(x_prev, uh)`` and ``dh/dx`` at ``(x, uh)``."""
    x, xp = ca.SX.sym("x", em.nx), ca.SX.sym("xp", em.nx)
    uh, p = ca.SX.sym("uh", em.nuh), ca.SX.sym("p", len(em.p))
    A = ca.jacobian(em.F(xp, uh, p), xp)
    C = ca.jacobian(em.h(x, uh, p), x)
    return ca.Function(f"{em.model.cname}_obs_lin", [xp, x, uh, p], [A, C], ["x_prev", "x", "uh", "p"], ["A", "C"])


def compress_channels(channels) -> str:
    """``theta1, theta2, theta3, omega1`` -> ``theta1..3, omega1``."""
    groups: dict[str, list[int]] = {}
    order: list[str] = []
    plain = []
    for c in channels:
        m = re.match(r"^(.*?)(\d+)$", c)
        if m:
            if m.group(1) not in groups:
                order.append(m.group(1))
                groups[m.group(1)] = []
            groups[m.group(1)].append(int(m.group(2)))
        else:
            order.append(c)
            plain.append(c)
    out = []
    for key in order:
        if key in plain:
            out.append(key)
            continue
        nums = groups[key]
        runs, start, prev = [], nums[0], nums[0]
        for v in nums[1:] + [None]:
            if v is not None and v == prev + 1:
                prev = v
                continue
            runs.append(f"{key}{start}" if start == prev else f"{key}{start}..{prev}")
            if v is not None:
                start = prev = v
        out.extend(runs)
    return ", ".join(out)


def _name_direction(v: np.ndarray, names, keep: float = 0.25):
    big = np.flatnonzero(np.abs(v) >= keep * np.max(np.abs(v)))
    big = big[np.argsort(-np.abs(v[big]))]
    lead = big[0]
    # lead with a twist if the direction has one (the message speaks of the twist)
    tw = [j for j in big if names[j].startswith("twist_")]
    if tw:
        lead = tw[0]
        big = np.array([lead] + [j for j in big if j != lead])
    c = v[big] / v[lead]
    terms = tuple((names[j], float(cj)) for j, cj in zip(big, c))
    text = names[big[0]]
    for nm, cj in terms[1:]:
        sign = "-" if cj < 0 else "+"
        mag = abs(cj)
        text += f" {sign} {nm}" if abs(mag - 1) < 0.05 else f" {sign} {mag:.2g} {nm}"
    return terms, text


def observability(em, X, UH, *, min_gain: float = MIN_GAIN, lin: ca.Function | None = None,
                  suggest=None, stick_speed: float | None = None, regime: str = "trajectory",
                  prior_weight: float = PRIOR_WEIGHT) -> ObservabilityReport:
    """Local observability of ``em`` along the trajectory ``X`` driven by ``UH`` (module docstring).

    Parameters
    ----------
    em : :class:`estimators.online.model.EstimationModel`
    X : (N, nx) estimator states at samples 0..N-1 (``x_k = F(x_{k-1}, uh_k)``)
    UH : (N, nuh) input histories (``uh_k``: the input over the sample that ended at k first)
    min_gain : threshold of a weak direction
    lin : a :func:`linearisation_function` of ``em`` (built if None)
    suggest : channels to name in the message's hint; None: the rig's unused torque channels
    stick_speed : [rad/s] a contact body slower than this is in stick (default: the model's
        ``eps``; 0 or less: trust the regularised friction everywhere)
    regime : words for the message ("start-up at the operating point", "steady sliding", ...)
    prior_weight : share of the prior's information added to the data's (module docstring)

    Returns
    -------
    ObservabilityReport
    """
    X = np.asarray(X, float)
    UH = np.asarray(UH, float)
    if X.ndim != 2 or X.shape[1] != em.nx or UH.shape != (X.shape[0], em.nuh) or X.shape[0] < 1:
        raise ConfigError(f"observability needs X of shape (N, {em.nx}) and UH of shape (N, {em.nuh}), got "
                          f"{X.shape} and {UH.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(UH))):
        raise ConfigError("observability needs a finite trajectory")
    lin = linearisation_function(em) if lin is None else lin
    stick_speed = em.stick_speed if stick_speed is None else float(stick_speed)
    n = em.nx
    w = 1.0 / np.sqrt(em.r)
    scales = np.sqrt(np.diag(em.P0))
    contacts = list(em.model.contacts)
    Phi = np.diag(scales)           # transition from the (scaled) start state
    V = np.zeros((n, 0))            # responses to the unknown stick torques so far
    rows, drows = [], []
    # a constant trajectory (steady sliding) has constant Jacobians: linearise once
    steady = bool(np.all(X == X[0]) and np.all(UH == UH[0]))
    N = X.shape[0]
    if steady:
        A0, C0 = (np.array(v) for v in lin(X[0], X[0], UH[0], em.p))
    else:      # every sample's Jacobians in one call (the per-call conversions were most of the time)
        Xp = np.vstack([X[:1], X[:-1]])
        AA, CC = (np.array(v) for v in lin.map(N)(Xp.T, X.T, UH.T, np.tile(np.asarray(em.p, float)[:, None], (1, N))))
    for k in range(N):
        A, C = (A0, C0) if steady else (AA[:, k * n:(k + 1) * n], CC[:, k * n:(k + 1) * n])
        if k:
            Phi = A @ Phi
            V = A @ V
            stuck = [j for j in contacts if abs(X[k - 1, j]) < stick_speed]
            if stuck:
                E = np.zeros((n, len(stuck)))
                E[stuck, range(len(stuck))] = 1.0
                V = np.hstack([V, E])
        Rk = w[:, None] * C
        rows.append(Rk @ Phi)
        drows.append(Rk @ V)
        if not np.all(np.isfinite(Phi)):
            raise ConfigError("observability: the linearised transition overflowed along the trajectory")
    O = np.vstack(rows)
    info = O.T @ O
    nd = V.shape[1]
    if nd:
        D = np.vstack([np.hstack([d, np.zeros((d.shape[0], nd - d.shape[1]))]) for d in drows])
        Ixd = O.T @ D
        info = info - Ixd @ np.linalg.pinv(D.T @ D, rcond=1e-12, hermitian=True) @ Ixd.T
        info = 0.5 * (info + info.T)
    ev = np.clip(np.linalg.eigvalsh(info), 0.0, None)[::-1]
    s = np.sqrt(ev)
    rank = int(np.sum(s >= min_gain))
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    # the end state: propagate the start's posterior (scaled units).  Computed as B B' with
    # B = Phis V diag(1/sqrt(lam)) from the eigen-decomposition of the regularised information:
    # sums of squares, no cancellation (the information spans 10 decades)
    Phis = Phi / scales[:, None]
    B = _end_factor(info, Phis, prior_weight)
    U_, sv, _ = np.linalg.svd(B, full_matrices=False)
    lam, vec = sv ** 2, U_
    weak = []
    for j in np.argsort(-lam):
        if lam[j] <= 1.0 / min_gain ** 2:
            break
        gain = float(np.sqrt(max(1.0 / lam[j] - prior_weight, 0.0)))
        terms, text = _name_direction(vec[:, j], em.names)
        weak.append(WeakDirection(gain, vec[:, j].copy(), terms, text))
    tw_idx = [em.names.index(t) for t in em.twist_names]
    twist_rel = np.sqrt(np.sum(B[tw_idx] ** 2, axis=1))
    twist_std = twist_rel * scales[tw_idx]
    observable = not weak
    twist_ok = bool(np.all(twist_rel <= 1.0 / min_gain))
    if suggest is None:
        from estimators.online.channels import default_channels
        # only a torque channel carries the absolute level a twist trades off against
        suggest = [c for c in default_channels(em.model) if c not in em.channels
                   and em.model.sensor_of(c).kind == "torque"]
    chans = compress_channels(em.channels)
    where = f" at {regime}" if regime else ""
    if not twist_ok:
        bad = [t for t, r in zip(em.twist_names, twist_rel) if r > 1.0 / min_gain]
        wd = next((w_ for w_ in weak if any(nm in bad for nm, _ in w_.terms)), weak[0] if weak else None)
        if wd is not None:
            lead = next((nm for nm, _ in wd.terms if nm in bad), bad[0])
            others = [nm for nm, _ in wd.terms if nm != lead]
            trade = f"{lead} trades off against {_and(others)}" if others else f"{lead} is not seen"
        else:
            trade = f"{bad[0]} keeps {twist_rel[em.twist_names.index(bad[0])]:.2g} of its prior uncertainty"
        hint = f"; add {_and(suggest)}" if suggest else ""
        cand = [nm for nm, _ in (wd.terms if wd is not None else ()) if nm.startswith(("load:", "offset:", "gain:"))]
        # which one augmented state, if known, would make the twist observable?
        drop = [nm for nm in cand
                if _twist_rel_without(info, Phis, em.names.index(nm), tw_idx, prior_weight).max() <= 1.0 / min_gain]
        if drop or cand:
            hint += f"{'; or' if hint else ';'} drop {_or(drop) if drop else _and(cand)}"
        message = f"twist not observable{where}: {trade} (channels {chans}{hint})"
        status = Status.WARNING
    elif not observable:
        message = (f"twist observable{where} (std {_fmt_std(em.twist_names, twist_std)}); weak: {weak[0].text} "
                   f"(channels {chans})")
        status = Status.OK
    else:
        message = f"observable{where} (twist std {_fmt_std(em.twist_names, twist_std)}; channels {chans})"
        status = Status.OK
    return ObservabilityReport(rank, n, cond, s, em.names, scales, tuple(weak), observable, twist_ok, twist_std,
                               em.channels, X.shape[0], float(min_gain), status, message, em.twist_names, regime)


def _end_factor(info, Phis, prior_weight) -> np.ndarray:
    """``B`` with ``B B' = Phis (info + w I)^-1 Phis'`` (the end state's covariance, scaled)."""
    ev, V = np.linalg.eigh(info)
    return (Phis @ V) / np.sqrt(np.clip(ev, 0.0, None) + prior_weight)[None, :]


def _twist_rel_without(info, Phis, j, tw_idx, prior_weight) -> np.ndarray:
    """Twist standard deviation (prior units) at the end if state ``j`` were known exactly."""
    keep = [i for i in range(info.shape[0]) if i != j]
    B = _end_factor(info[np.ix_(keep, keep)], Phis[:, keep], prior_weight)
    return np.sqrt(np.sum(B[tw_idx] ** 2, axis=1))


def _or(items) -> str:
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " or " + items[-1]


def _and(items) -> str:
    items = list(items)
    if not items:
        return "nothing"
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _fmt_std(names, std) -> str:
    return ", ".join(f"{n} {v:.2g} rad" for n, v in zip(names, std))
