"""The log as the data-derived guesses see it (:mod:`estimators.identify.guess`).

:class:`GuessData`: a log's inputs corrected with the base set, the measured speeds, their
derivatives, the encoder angles and each contact's friction terms; :func:`stuck_threshold`: the
speed below which a body counts as stuck; :func:`far_side`, :func:`far_body`: the bodies beyond
a connection, away from the drive; :func:`active_contacts`: the contacts with a real load.
"""

from __future__ import annotations

import math

import numpy as np

from models.logs import Log
from models.rig.spec import NODE_DRIVE, NODE_GROUND
from models.sensors import channel_std
from models.signals import moving_average

__all__ = ["GuessData", "N_AVG", "stuck_threshold", "far_side", "far_body", "active_contacts"]


def stuck_threshold(model, channel: str, dt: float, omega_scale: float, n_avg: int = 1) -> float:
    """Below this a measured speed (averaged over ``n_avg`` samples) counts as stuck: half an
    encoder tick over the averaging window, or 3 standard deviations of a speed sensor's mean;
    at least 1e-3 of the speed scale."""
    s = model.sensor_of(channel)
    if s is not None and s.kind == "encoder":
        thr = 0.5 * 2 * math.pi / (s.ticks * s.ratio) / (n_avg * dt)
    else:
        thr = 3 * channel_std(model, channel, dt) / math.sqrt(n_avg)
    return max(thr, 1e-3 * abs(omega_scale), 1e-9)


#: samples the measured speed is averaged over before stick is detected (a quantised encoder
#: speed of a slowly sliding body reads 0 in single samples)
N_AVG = 5


class GuessData:
    """The log's inputs (corrected with the base set), measured speeds and their derivatives."""

    def __init__(self, model, log: Log, P: dict, input_row: str):
        self.model, self.log, self.dt, self.P = model, log, log.dt, P
        n = len(log.t)
        U = np.column_stack([np.asarray(log[n_], float) for n_ in model.inputs]) if model.nu else np.zeros((n, 0))
        Um = np.array(model.input_from_measured([U[:, j] for j in range(model.nu)], P)).T if model.nu else U
        self.u = {name: Um[:, j] for j, name in enumerate(model.inputs)}
        self.speeds: dict[str, np.ndarray] = {}
        for b in model.bodies:
            ch = model.speed_channel(b)
            if ch is not None and ch in log.channels:
                self.speeds[b] = np.asarray(log[ch], float)
        if not model.drive.on_body:             # a prescribed speed: the node "drive" turns at the input
            self.speeds[NODE_DRIVE] = self.u[model.drive_input]
        self.speeds[NODE_GROUND] = np.zeros(n)

    def speed(self, node):
        return self.speeds.get(node)

    def accel(self, node):
        w = self.speeds.get(node)
        return None if w is None else np.gradient(moving_average(w, 5), self.dt)

    def angle(self, node):
        ch = self.model.angle_channel(node) if node != NODE_DRIVE else next(
            (s.channels[0] for s in self.model.sensors if s.kind == "encoder" and s.target == NODE_DRIVE), None)
        return np.asarray(self.log[ch], float) if ch is not None and ch in self.log.channels else None

    def scale(self, contact):
        """``N r`` of a contact over the log (array), 1 where it has neither."""
        N, r, _ = self.model.contact_args(contact, self.P, self.u)
        return np.broadcast_to(np.asarray(N, float) * float(r), self.log.t.shape)

    def friction_terms(self, contact):
        """The contact's friction magnitude over the log as ``rest + sum(value(ref) * column)``
        over the parameters its law is linear in (:attr:`models.friction.FrictionLaw.linear_params`):
        ``([(ref, column)], rest)``, arrays over the log; None if the law declares none."""
        law = self.model.law(contact.name)
        names = law.linear_params
        if not names:
            return None
        N, r, LP = self.model.contact_args(contact, self.P, self.u)
        N = np.broadcast_to(np.asarray(N, float), self.log.t.shape)
        aw = np.abs(self.speed(contact.body))
        zero = dict({k: float(v) for k, v in LP.items()}, **{n: 0.0 for n in names})
        rest = np.asarray(law.magnitude_at(aw, N, float(r), zero), float)
        refs = dict(contact.params)
        terms = [(refs[n], np.asarray(law.magnitude_at(aw, N, float(r), dict(zero, **{n: 1.0})), float) - rest)
                 for n in names]
        return terms, rest


def far_side(model, conn) -> set[str]:
    """Bodies on the side of ``conn`` away from the reference node (the drive)."""
    ref = model.spec.reference_node
    adj: dict[str, list] = {}
    for c in model.spec.connections:
        if c is conn:
            continue
        adj.setdefault(c.a, []).append(c.b)
        adj.setdefault(c.b, []).append(c.a)

    def reach(start):
        seen, stack = {start}, [start]
        while stack:
            n = stack.pop()
            for m in adj.get(n, []):
                if m not in seen and m != NODE_GROUND:
                    seen.add(m)
                    stack.append(m)
        return seen

    a_side = reach(conn.a)
    side = reach(conn.b) if ref in a_side or conn.a == NODE_DRIVE else a_side
    return {b for b in side if b in model.bodies}


def active_contacts(model, data, contacts):
    """Contacts that carry a real normal load: mean ``|N r|`` above 5 % of the largest (a logged
    zero force with load-cell noise is not a load)."""
    sc = {c.name: float(np.mean(np.abs(data.scale(c)))) for c in model.spec.contacts}
    top = max(sc.values(), default=0.0)
    return [c for c in contacts if sc[c.name] > max(0.05 * top, 1e-12)]


def far_body(model, conn):
    """The body of ``conn`` on its side away from the drive (None if that end is the ground)."""
    side = far_side(model, conn)
    for n in (conn.a, conn.b):
        if n in side:
            return n
    return None
