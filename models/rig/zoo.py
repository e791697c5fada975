"""A generator of physically plausible rig files: the rig zoo (tests/test_rig_zoo.py draws them with
hypothesis) and the benchmark's generated scenarios (:mod:`mitigate.benchmark.generate` draws them
from a seed).

A rig is 1-6 bodies in a chain or a tree hung from the drive, at a scale from a lab rig
(1e-3 kg m^2, ~1 N m) to a field string (1e3 kg m^2, ~10 kN m), with a speed, torque or DC-motor
drive (electrical time constant L/R from 0.05 to 5 ms), one contact with a friction law of the
registry on a leaf body, a random subset of sensors and freely chosen input names (some of them
the measurement Function's own argument names).  Every number follows from a few drawn
quantities (inertia scale, the chain's frequency, the sliding speed, the twist the friction
loads the string with), so the rig is consistent at any scale: its friction torque is carried by
its springs, its motor can carry that torque at that speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

__all__ = ["ZooRig", "Draw", "SeededDraw", "zoo_rig", "LAWS", "DRIVE_INPUT_NAMES", "NORMAL_INPUT_NAMES"]

#: laws of the registry a generated rig may use (every registered law: test_rig_zoo checks it)
LAWS = ("stribeck", "bit_rock", "vahid_araghi", "coulomb", "leadscrew")
DRIVE_INPUT_NAMES = ("omega_ref", "w_set", "u", "tau_top", "speed_cmd")
NORMAL_INPUT_NAMES = ("n_brake", "f_pin", "x", "wob", "p", "load")


@dataclass(frozen=True)
class ZooRig:
    """A generated rig: its TOML text and what it was drawn from."""

    text: str
    n_bodies: int
    drive: str
    law: str
    scale: float            # inertia scale [kg m^2]
    speed: float            # nominal sliding speed [rad/s]
    torque: float           # friction torque at the operating point [N m]
    drive_input: str
    normal_input: str
    contact_body: str
    sensors: tuple[str, ...]

    def describe(self) -> str:
        return (f"{self.n_bodies} bodies, {self.drive} drive, {self.law}, J ~ {self.scale:.3g} kg m^2, "
                f"T ~ {self.torque:.3g} N m, w0 {self.speed:.3g} rad/s, inputs {self.drive_input}/{self.normal_input}, "
                f"sensors {', '.join(self.sensors)}")


def _q(v: float) -> str:
    return repr(float(v))


class Draw(Protocol):
    """Where the generator's numbers come from: hypothesis (the zoo's tests) or a seeded generator
    (:class:`SeededDraw`).  ``label`` names the draw (hypothesis shows it when a test fails)."""

    def floats(self, low: float, high: float, label: str | None = None) -> float: ...

    def integers(self, low: int, high: int, label: str | None = None) -> int: ...

    def booleans(self, label: str | None = None) -> bool: ...

    def sampled_from(self, items: Sequence, label: str | None = None): ...


class SeededDraw:
    """:class:`Draw` from a :class:`numpy.random.Generator` (uniform floats, integers in ``[low, high]``)."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng

    def floats(self, low, high, label=None):
        return float(self.rng.uniform(low, high))

    def integers(self, low, high, label=None):
        return int(self.rng.integers(low, high + 1))

    def booleans(self, label=None):
        return bool(self.rng.integers(0, 2))

    def sampled_from(self, items, label=None):
        items = tuple(items)
        return items[int(self.rng.integers(0, len(items)))]


def zoo_rig(d: "Draw", max_bodies: int = 6, drives=("speed", "torque", "dc_motor"), log_scale=(-3.0, 3.0),
            log_tau_e=(math.log10(5e-5), math.log10(5e-3)), laws=LAWS, drop_sensors: bool = True,
            servo: bool | None = None) -> ZooRig:
    """A rig (module docstring) drawn by ``d`` (:class:`Draw`); ``drives``, ``log_scale`` (log10 of the
    inertia scale), ``log_tau_e`` (log10 of a DC motor's L/R [s]) and ``laws`` narrow the draw;
    ``drop_sensors=False`` keeps every sensor, ``servo`` forces a servo on the contact (True) or
    none (False) instead of drawing it."""
    # (the draws are arranged so that hypothesis' simplest example is a rich rig: the most bodies,
    # every sensor, a servo, a Stribeck contact)
    n = max_bodies - d.integers(0, max_bodies - 1, "bodies fewer than the most")
    tree = d.booleans("tree")
    parents = [-1] + [d.integers(0, i - 1) if tree else i - 1 for i in range(1, n)]
    leaves = [i for i in range(n) if i not in parents]
    scale = 10.0 ** d.floats(*log_scale, "log10 inertia scale")
    f0 = d.floats(0.5, 3.0, "chain frequency [Hz]")
    speed = d.floats(1.0, 6.0, "sliding speed [rad/s]")
    twist = d.floats(0.05, 0.5, "twist under the friction torque [rad]")
    drive = d.sampled_from(tuple(drives), "drive")
    law = d.sampled_from(tuple(laws), "law")
    din = d.sampled_from(DRIVE_INPUT_NAMES, "drive input")
    nin = d.sampled_from([x for x in NORMAL_INPUT_NAMES if x != din], "normal input")
    contact = leaves[d.integers(0, len(leaves) - 1, "contact leaf")]
    J = [scale * d.floats(0.5, 2.0) for _ in range(n)]
    w2 = (2 * math.pi * f0) ** 2
    k = [J[i] * w2 * d.floats(0.5, 2.0) for i in range(n)]
    zeta = [d.floats(0.005, 0.05) for _ in range(n)]
    c = [2 * zeta[i] * math.sqrt(k[i] * J[i]) for i in range(n)]
    # the friction torque: the springs from the drive to the contact body carry it with `twist`
    path, i = [], contact
    while i >= 0:
        path.append(i)
        i = parents[i]
    k_series = 1.0 / sum(1.0 / k[j] for j in path)
    T = k_series * twist
    r = 0.05
    mu_k = 0.3
    N = T / (r * mu_k)
    if law == "leadscrew":
        # a self-locking screw (thread friction above the lead angle's tangent, seed 002: 0.218 against
        # tan 5.57 deg = 0.098): pitch radius r, the axial load N is the normal input, the support
        # friction T0 2 % and the slider resistance F0 1 % of the load; forward, the thread's torque is
        # r xi(mu1) (N - F0) + T0 = T (seed 002 eqs. 9.7, 9.31)
        lam = d.floats(0.05, 0.15, "lead angle [rad]")
        mu_k = d.floats(0.2, 0.3, "thread friction mu1")
        xi = (mu_k - math.tan(lam)) / (1 + mu_k * math.tan(lam))
        N = 0.98 * T / (r * xi * 0.99)
        # the nut's translating mass adds tan(lam) |xi| m r^2 (seed 002 eq. 9.31): 5 % of the screw's inertia
        m_nut = 0.05 * J[contact] / (r ** 2 * math.tan(lam))
    names = [f"b{i}" for i in range(n)]

    L = ["[rig]", f'name = "zoo_{n}{drive[0]}{law[:2]}"',
         f'description = "generated: {n} bodies, {drive} drive, {law}"',
         f'objective_body = "{names[contact]}"']
    op = {nin: f'"{_q(N)} N"'}
    if drive == "torque":
        op[din] = f'"{_q(T)} N m"'
        op["speed"] = f'"{_q(speed)} rad/s"'
    else:
        op[din] = f'"{_q(speed)} rad/s"'
    L.append("operating_point = { " + ", ".join(f"{key} = {v}" for key, v in op.items()) + " }")
    L += ["", "[parameters]"]
    for i in range(n):
        L.append(f'J{i} = {{ value = {_q(J[i])}, unit = "kg m^2", positive = true }}')
        L.append(f'k{i} = {{ value = {_q(k[i])}, unit = "N m/rad", positive = true }}')
        L.append(f'c{i} = {{ value = {_q(c[i])}, unit = "N m s/rad" }}')
    L.append(f'r_c = {{ value = {r}, unit = "m", positive = true }}')
    if law == "coulomb":
        L.append(f"mu_k = {{ value = {mu_k} }}")
        law_keys = {"mu_k": "mu_k"}
    elif law == "stribeck":
        L += ["mu_s = { value = 0.5 }", f"mu_k = {{ value = {mu_k} }}",
              f'v_s = {{ value = {_q(0.3 * speed)}, unit = "rad/s", positive = true }}']
        law_keys = {"mu_s": "mu_s", "mu_k": "mu_k", "v_s": "v_s"}
    elif law == "bit_rock":
        L += ["mu_sb = { value = 0.5 }", f"mu_cb = {{ value = {mu_k} }}",
              f'v_b = {{ value = {_q(0.3 * speed)}, unit = "rad/s", positive = true }}',
              f'c_b = {{ value = {_q(0.01 * T / speed)}, unit = "N m s/rad" }}']
        law_keys = {"mu_sb": "mu_sb", "mu_cb": "mu_cb", "v_b": "v_b", "c_b": "c_b"}
    elif law == "vahid_araghi":
        L += [f"mu1 = {{ value = {mu_k} }}", "mu2 = { value = 0.2 }", 'mu3 = { value = 0.0, unit = "s/rad" }',
              f'r0 = {{ value = {_q(1.0 / (0.3 * speed))}, unit = "s/rad" }}', "sm = { value = 1.0 }"]
        law_keys = {"mu1": "mu1", "mu2": "mu2", "mu3": "mu3", "r0": "r0", "sm": "sm"}
    else:
        # seed 002 Table 9.5's Stribeck part (mu2 / mu1 ~ 0.1) made clearer, decaying over 0.3 of the
        # speed; the smoothing of eq. (9.33) over 2 % of the speed (the exact plant does not use it)
        L += [f"mu1 = {{ value = {_q(mu_k)} }}", f"mu2 = {{ value = {_q(0.3 * mu_k)} }}",
              'mu3 = { value = 0.0, unit = "s/rad" }',
              f'r0 = {{ value = {_q(1.0 / (0.3 * speed))}, unit = "s/rad" }}', "sm = { value = 1.0 }",
              f'lam = {{ value = {_q(lam)}, unit = "rad" }}', f'm_nut = {{ value = {_q(m_nut)}, unit = "kg" }}',
              f'F0 = {{ value = {_q(0.01 * N)}, unit = "N" }}', f'T0 = {{ value = {_q(0.02 * T)}, unit = "N m" }}',
              f'r1 = {{ value = {_q(1.0 / (0.02 * speed))}, unit = "s/rad", positive = true }}']
        law_keys = {"mu1": "mu1", "mu2": "mu2", "mu3": "mu3", "r0": "r0", "sm": "sm", "lam": "lam", "m": "m_nut",
                    "F0": "F0", "T0": "T0", "r1": "r1"}
    motor = drive == "dc_motor"
    if motor:
        tau_e = 10.0 ** d.floats(*log_tau_e, "L/R [s]")
        ratio = 20.0
        Jtot = sum(J)
        Jm = 0.3 * Jtot / ratio ** 2
        i_max = 10.0
        KT = 4.0 * T / (ratio * i_max)
        R = 1.0
        w_c = 2 * math.pi * 20.0 * f0                      # the speed loop, well above the string
        kp = w_c * (1.3 * Jtot) * R / (ratio * KT)
        ki = kp * w_c / 5.0
        v_max = 3.0 * (R * i_max + KT * ratio * 3.0 * speed)
        L += [f'L = {{ value = {_q(tau_e * R)}, unit = "H", positive = true }}',
              f'R = {{ value = {R}, unit = "ohm", positive = true }}',
              f'KT = {{ value = {_q(KT)}, unit = "N m/A", positive = true }}',
              f'KE = {{ value = {_q(KT)}, unit = "V s/rad" }}',
              f'Tf = {{ value = {_q(0.01 * T / ratio)}, unit = "N m" }}',
              f'Cm = {{ value = {_q(1e-4 * T / (ratio * speed * ratio))}, unit = "N m s/rad" }}',
              f'Jm = {{ value = {_q(Jm)}, unit = "kg m^2", positive = true }}',
              f"ratio = {{ value = {ratio} }}",
              f'kp = {{ value = {_q(kp)}, unit = "V s/rad" }}', f'ki = {{ value = {_q(ki)}, unit = "V/rad" }}',
              f'v_max = {{ value = {_q(v_max)}, unit = "V" }}', f'i_max = {{ value = {i_max}, unit = "A" }}']
    L.append("")
    if motor:
        L += ["[bodies.mot]", "inertia = 0.0"]
    if drive == "torque":
        L += ["[bodies.top]", f'inertia = {_q(0.5 * sum(J))}']
    for i in range(n):
        L += [f"[bodies.{names[i]}]", f'inertia = "J{i}"']
    top = {"speed": "drive", "torque": "top", "dc_motor": "mot"}[drive]
    for i in range(n):
        other = top if parents[i] < 0 else names[parents[i]]
        L += [f"[connections.s{i}]", f'between = ["{names[i]}", "{other}"]', f'stiffness = "k{i}"',
              f'damping = "c{i}"']
    L += ["[contacts.pin]", f'body = "{names[contact]}"', f'law = "{law}"', f'normal = "{nin}"', 'radius = "r_c"']
    L += [f'{key} = "{v}"' for key, v in law_keys.items()]
    L += ["[drive]", f'kind = "{drive}"', f'input = "{din}"']
    if drive != "speed":
        L.append(f'body = "{top}"')
    if motor:
        L += [f'{p} = "{p}"' for p in ("L", "R", "KT", "KE", "Tf", "Cm", "Jm", "ratio", "kp", "ki", "v_max", "i_max")]
    servo = (not d.booleans("no servo")) if servo is None else servo
    if servo:
        L += ["[actuators.pin_servo]", 'kind = "servo"', f'input = "{nin}"', 'n_min = "0 N"',
              f'n_max = "{_q(2.5 * N)} N"', f'rate_max = "{_q(10 * N)} N/s"', 'tau = "30 ms"']
    # sensors: a random subset (at least one encoder, else nothing can be estimated)
    cand = [("enc_c", f'kind = "encoder"\nbody = "{names[contact]}"\nticks = 2048')]
    if drive != "speed":
        cand.append(("enc_d", f'kind = "encoder"\nbody = "{top}"\nticks = 1024'))
        cand.append(("tq", 'kind = "torque"\nat = "drive"' + (f'\nnoise = "{_q(0.002 * T)} N m"' if drive == "torque" else "")))
    else:
        cand.append(("enc_d", 'kind = "encoder"\nbody = "drive"\nticks = 1024'))
    cand.append(("cell", f'kind = "load_cell"\ncontact = "pin"\nnoise = "{_q(0.002 * N)} N"'))
    if n > 1:
        cand.append(("enc_0", f'kind = "encoder"\nbody = "{names[0]}"\nticks = 1024'))
    keep = [s for s in cand if not (drop_sensors and d.booleans(f"drop sensor {s[0]}"))]
    if not any(s[0].startswith("enc") for s in keep):
        keep.append(cand[0])
    for name, body in keep:
        L += [f"[sensors.{name}]", body]
    return ZooRig("\n".join(L) + "\n", n, drive, law, scale, speed, T, din, nin, names[contact],
                  tuple(s[0] for s in keep))
