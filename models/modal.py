"""Linearised modal analysis of any rig about steady sliding.

Three questions are answered here, for every rig file:

1. *Which torsional modes does the rig have?*  :func:`modes` gives natural frequencies,
   damping ratios and mode shapes for

   - ``"free"``: the mechanical chain only (the bodies' inertias, the motor's rotor reflected
     through its gearbox, the springs and dampers; no motor electrics, no friction): the
     thesis eq. (3-3) model plus the shaft damping, with its rigid-body 0 Hz mode.  A speed
     drive's node and the frame are held;
   - ``"clamped"``: the same chain with the drive body held as well;
   - ``"closed"``: the full model (DC motor, PI speed loop, friction) linearised at steady
     sliding (:func:`linearise`).

   :func:`compare_measured` sets them against the frequencies the rig file gives as
   measured (``[rig] measured_modes_hz``; the thesis: 0, 0.396 and 1.781 Hz, Fig. 3.7).
   :func:`stick_slip_period` is the rig's stick-slip period estimate, the lowest mode with the
   drive's own boundary condition; the metrics' windows, the controllers' tuning rules and the
   NMPC's defaults all ask it.
2. *Is steady sliding stable?*  :func:`sliding_stability` returns the largest real part of
   the linearisation; :func:`stability_map` maps it over (normal force, speed), the force being the
   rig's actuated input over its rated range (:func:`map_axis`).  A positive
   value means the falling friction law beats the damping and the rig falls into
   stick-slip from any small disturbance.
3. *What linear model do controllers and observers see?*  :class:`LinearModel` carries
   A, B, C, D and a python-control ``StateSpace``.

Regularisation
--------------
:func:`linearise` differentiates the regularised model ``model.ode(eps)``.  Its friction
torque is ``tanh(v/eps) T(|v|)``, whose slope is ``T(|v|) sech^2(v/eps)/eps + tanh(v/eps)
T'(|v|)``.  At a sliding speed ``|v| >> eps`` the first term vanishes (``sech^2`` is below
1e-20 for ``|v| > 25 eps``) and the slope is the law's own, i.e. the linearisation is
physically the sliding one.  **eps must therefore be much smaller than the sliding speed**;
:func:`linearise` flags operating points with ``|v| < 10 eps`` in ``message``.

References
----------
thesis Ch. 3, eqs. (3-3)-(3-7), (3-9), (3-13), Fig. 3.7.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property

import casadi as ca
import numpy as np

from models.errors import ConfigError
from models.params import ParameterSet
from models.rig import get_model
from models.rig.steady import nominal_operating_point
from models.status import Outcome, Status

__all__ = [
    "LinearModel",
    "ModalResult",
    "VARIANTS",
    "linearise",
    "operating_point",
    "chain_matrices",
    "modes",
    "compare_measured",
    "stick_slip_frequency",
    "stick_slip_period",
    "params_of",
]

#: Modal variants: mechanical chain free / clamped at the drive, or the full closed loop.
VARIANTS = ("free", "clamped", "closed")


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class LinearModel(Outcome):
    """A linearisation ``dx = A dx + B du``, ``dy = C dx + D du`` about ``(x_op, u_op)``.

    Attributes
    ----------
    A, B, C, D : numpy arrays (nx, nx), (nx, nu), (ny, nx), (ny, nu), SI units of the states
    x_op, u_op : operating point (state, input)
    states, inputs, outputs : names
    eps : regularisation of the friction used [rad/s]
    ss : the same system as a python-control ``StateSpace`` (property, built on first use)
    status : Status.OK, or Status.WARNING if ``x_op`` is not an equilibrium or the sliding
        speed is not >> eps (``message`` says which)
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    x_op: np.ndarray
    u_op: np.ndarray
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    eps: float
    model: str
    status: Status = Status.OK
    message: str = "ok"

    @cached_property
    def ss(self):
        """The system as a python-control ``StateSpace`` with named signals (built on first use)."""
        import control  # lazily: importing python-control (scipy.signal) costs seconds at CLI start-up

        return control.ss(self.A, self.B, self.C, self.D, states=list(self.states), inputs=list(self.inputs),
                          outputs=list(self.outputs))

    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of A [1/s], sorted by magnitude."""
        ev = np.linalg.eigvals(self.A)
        return ev[np.argsort(np.abs(ev), kind="stable")]


@dataclass(frozen=True)
class ModalResult(Outcome):
    """Modes of one variant of a rig.

    Attributes
    ----------
    model, variant : which system
    freq_hz : (m,) undamped natural frequency |lambda|/(2 pi) of each mode [Hz] (0 for the
        rigid-body mode)
    damped_hz : (m,) damped frequency |Im lambda|/(2 pi) [Hz] (0: non-oscillatory)
    damping : (m,) damping ratio -Re(lambda)/|lambda| (negative: an unstable mode)
    oscillatory : (m,) bool, complex pair
    shapes : (m, ndof) real mode shapes on ``dof_names``, normalised so the component of
        largest magnitude is +1 (complex eigenvectors rotated to that component)
    dof_names : the degrees of freedom of ``shapes`` (body angles for the mechanical chain,
        body speeds for the closed loop)
    eigenvalues : (n,) all eigenvalues [1/s], sorted by magnitude
    max_real : largest real part [1/s] (excluding the rigid-body zero)
    status : Status; message : detail
    rig : how the rig is referred to in files (its shipped name or its file's absolute path;
        :func:`compare_measured` reloads the rig from it)
    """

    model: str
    variant: str
    freq_hz: np.ndarray
    damped_hz: np.ndarray
    damping: np.ndarray
    oscillatory: np.ndarray
    shapes: np.ndarray
    dof_names: tuple[str, ...]
    eigenvalues: np.ndarray
    max_real: float
    status: Status = Status.OK
    message: str = "ok"
    rig: str = ""

    def as_dict(self) -> dict:
        return {"model": self.model, "variant": self.variant, "freq_hz": self.freq_hz.tolist(),
                "damped_hz": self.damped_hz.tolist(), "damping": self.damping.tolist(),
                "oscillatory": self.oscillatory.tolist(), "shapes": self.shapes.tolist(),
                "dof_names": list(self.dof_names), "max_real": self.max_real, "status": self.status.value,
                "message": self.message}


# ----------------------------------------------------------------------------- linearisation
def params_of(model, params):
    """``params`` checked against the rig, or the rig file's values when None."""
    return model.published() if params is None else model.check_params(params)


def operating_point(model, params: ParameterSet | None = None, *, omega: float | None = None,
                    load: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The rig's sliding operating point ``(u, x_op or None)``:
    :func:`models.rig.steady.nominal_operating_point` (a rig name or file is accepted here)."""
    return nominal_operating_point(get_model(model), params, omega=omega, load=load)


def _functions(model, eps: float, outputs: tuple[str, ...]):
    """(ode, Newton equilibrium solver g(x; u, p), Jacobian Function), cached on the model per eps/outputs."""
    key = ("modal", eps, outputs)
    cache = model._fcache
    if key not in cache:
        f = model.ode(eps)
        x, uu, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
        xd = f(x, uu, p)
        g = ca.Function("g", [x, ca.vertcat(uu, p)], [xd])
        solver = ca.rootfinder("eq", "newton", g, {"abstol": 1e-12, "max_iter": 100})
        y = model.meas_vector(list(outputs))(x, uu, p)
        jac = ca.Function(f"{model.cname}_lin", [x, uu, p],
                          [ca.jacobian(xd, x), ca.jacobian(xd, uu), ca.jacobian(y, x), ca.jacobian(y, uu), xd],
                          ["x", "u", "p"], ["A", "B", "C", "D", "xdot"])
        cache[key] = (f, solver, jac)
    return cache[key]


def linearise(model, params: ParameterSet | None, u, eps: float | None = None, x_op=None,
              outputs: tuple[str, ...] | None = None) -> LinearModel:
    """Linearise the regularised model about steady sliding.

    Parameters
    ----------
    model : a rig (name, file or model)
    params : its parameter set (published or fitted; None: published)
    u : (nu,) constant input of the operating point (rig3: omega_ref [rad/s], N1, N2 [N])
    eps : friction regularisation [rad/s]; must be << the sliding speed (module docstring)
    x_op : (nx,) operating state; default: the equilibrium of ``model.ode(eps)`` at ``u``
    outputs : output names (default: every sensor channel and state quantity that needs no
        absolute angle)

    Returns
    -------
    LinearModel
    """
    model = get_model(model)
    params = params_of(model, params)
    u = np.asarray(u, dtype=float).ravel()
    if u.shape != (model.nu,) or not np.all(np.isfinite(u)):
        raise ConfigError(f"u must be {model.nu} finite numbers {model.inputs}, got {u}")
    eps = model.eps_default if eps is None else float(eps)
    if not eps > 0:
        raise ConfigError(f"eps must be > 0 rad/s, got {eps}")
    if outputs is None:
        angles = {s.channels[0] for s in model.sensors if s.kind == "encoder"}
        outputs = tuple(n for n in model.output_names() if n not in angles)
    f, solver, jac = _functions(model, eps, tuple(outputs))
    if x_op is None:
        guess = model.sliding_guess(u, params)
        x_op = np.array(solver(ca.DM(guess), ca.DM(np.concatenate([u, params.vector()])))).ravel()
    x_op = np.asarray(x_op, dtype=float).ravel()
    if x_op.shape != (model.nx,):
        raise ConfigError(f"x_op must have {model.nx} entries {model.states}, got shape {x_op.shape}")
    A, B, C, D, r = (np.array(v, dtype=float) for v in jac(x_op, u, params.vector()))
    res = float(np.max(np.abs(r))) if r.size else 0.0
    msgs = []
    if not np.all(np.isfinite(A)):
        msgs.append("non-finite Jacobian")
    if res > 1e-8:
        msgs.append(f"x_op is not an equilibrium (max |xdot| = {res:.2e})")
    speeds = [abs(x_op[i]) for i in model.contacts]
    if speeds and min(speeds) < 10 * eps:
        msgs.append(f"a contact speed {min(speeds):.3g} rad/s is not >> eps = {eps:g} rad/s: "
                    "the regularisation, not the sliding friction, sets the slope")
    return LinearModel(A, B, C, D, x_op, u, tuple(model.states), tuple(model.inputs), tuple(outputs), eps,
                       model.name, Status.WARNING if msgs else Status.OK, "; ".join(msgs) or "ok")


# ----------------------------------------------------------------------------- mechanical chain
def chain_matrices(model, params: ParameterSet | None = None, *, clamped: bool = False, damped: bool = True):
    """Mass, damping and stiffness matrices of a rig's mechanical chain (thesis eq. 3-3).

    The degrees of freedom are the bodies' angles; a DC motor's rotor adds ``ratio^2 Jm`` to
    the body it drives; springs and dampers to the frame or to a speed drive's node hold that
    end fixed; backlash is ignored (teeth in contact); friction is left out.

    Parameters
    ----------
    model : a rig (name, file or model); params : its parameters (None: published)
    clamped : hold the drive body as well (a DC motor or torque drive)
    damped : include the dampers (eq. 3-3 itself is undamped)

    Returns
    -------
    M, Cd, K : (n, n) arrays [kg m^2], [N m s/rad], [N m/rad]; the dof names
    """
    model = get_model(model)
    params = params_of(model, params)
    P = params.as_dict()
    bodies = list(model.bodies)
    n = len(bodies)
    idx = {b: i for i, b in enumerate(bodies)}
    M = np.zeros((n, n))
    K = np.zeros((n, n))
    Cd = np.zeros((n, n))
    for b in bodies:
        M[idx[b], idx[b]] = model.inertia(b, P)
    for c in model.spec.connections:
        for mat, ref in ((K, c.stiffness), (Cd, c.damping if damped else None)):
            if ref is None:
                continue
            v = ref.value(P)
            ia, ib = idx.get(c.a), idx.get(c.b)
            for i in (ia, ib):
                if i is not None:
                    mat[i, i] += v
            if ia is not None and ib is not None:
                mat[ia, ib] -= v
                mat[ib, ia] -= v
    dofs = tuple(f"theta_{b}" for b in bodies)
    if clamped:
        if not model.drive.on_body:          # a prescribed speed already holds its end of the chain
            return M, Cd, K, dofs
        keep = [i for i, b in enumerate(bodies) if b != model.drive_body]
        sel = np.ix_(keep, keep)
        return M[sel], Cd[sel], K[sel], tuple(dofs[i] for i in keep)
    return M, Cd, K, dofs


def _second_order_ss(M, Cd, K) -> np.ndarray:
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ Cd]])


def _modes_from_A(A: np.ndarray, dof_index: list[int], dof_names, model, variant: str,
                  zero_tol: float = 1e-6) -> ModalResult:
    """One mode per complex pair (Im > 0) and per real eigenvalue; the zero cluster is one
    rigid-body mode."""
    import scipy.linalg          # here: importing it costs every process that never asks for modes 0.4 s

    lam, V = scipy.linalg.eig(A)
    order = np.argsort(np.abs(lam), kind="stable")
    lam, V = lam[order], V[:, order]
    scale = max(1.0, float(np.max(np.abs(lam)))) if lam.size else 1.0
    rows = []
    seen_zero = False
    for j, l in enumerate(lam):
        if abs(l) < zero_tol * scale:
            if seen_zero:
                continue
            seen_zero = True
        elif l.imag < -1e-9 * scale:
            continue  # the conjugate of a listed pair
        v = V[dof_index, j]
        k = int(np.argmax(np.abs(v)))
        shape = np.real(v / v[k]) if abs(v[k]) > 0 else np.zeros(len(dof_index))
        a = abs(l)
        if abs(l) < zero_tol * scale:
            rows.append((0.0, 0.0, 0.0, False, shape))
        else:
            rows.append((a / (2 * math.pi), abs(l.imag) / (2 * math.pi), -l.real / a,
                         bool(abs(l.imag) > 1e-9 * scale), shape))
    rows.sort(key=lambda r: r[0])
    nonzero = lam[np.abs(lam) >= zero_tol * scale]
    max_real = float(np.max(nonzero.real)) if nonzero.size else 0.0
    ok = bool(np.all(np.isfinite(lam)))
    return ModalResult(
        model.name, variant,
        np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
        np.array([r[3] for r in rows], dtype=bool), np.array([r[4] for r in rows]), tuple(dof_names),
        lam, max_real, Status.OK if ok else Status.FAILED, "ok" if ok else "non-finite eigenvalues", rig=model.key)


def modes(model="rig3", params: ParameterSet | None = None, variant: str = "closed", *, u=None,
          omega: float | None = None, load: float | None = None, eps: float | None = None,
          damped: bool = True) -> ModalResult:
    """Natural frequencies, damping ratios and mode shapes of one variant.

    Parameters
    ----------
    model : a rig (name, file or model)
    params : parameter set (default: published)
    variant : "free" | "clamped" (mechanical chain) or "closed" (linearised at steady sliding;
        "sliding" is accepted as the same)
    u : input of the operating point (closed); default from :func:`operating_point` with
        ``omega`` [rad/s] and ``load`` [N]
    eps : regularisation for the closed variant [rad/s]
    damped : include the dampers in the mechanical chain (free/clamped)

    Returns
    -------
    ModalResult
    """
    model = get_model(model)
    params = params_of(model, params)
    if variant == "sliding":
        variant = "closed"
    if variant not in VARIANTS:
        raise ConfigError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if variant in ("free", "clamped"):
        M, Cd, K, dofs = chain_matrices(model, params, clamped=(variant == "clamped"), damped=damped)
        A = _second_order_ss(M, Cd, K)
        return _modes_from_A(A, list(range(len(dofs))), dofs, model, variant)
    x_op = None
    if u is None:
        u, x_op = operating_point(model, params, omega=omega, load=load)
    lin = linearise(model, params, u, eps=eps, x_op=x_op)
    speed_idx = [i for i, s in enumerate(model.states) if s.startswith("omega_")]
    res = _modes_from_A(lin.A, speed_idx, [model.states[i] for i in speed_idx], model, "closed")
    if lin.status is not Status.OK:      # the linearisation's warning (or failure) is the modes' too
        res = replace(res, status=lin.status, message=lin.message)
    return res


def compare_measured(result: ModalResult, measured=None) -> list[tuple[str, float, float, float]]:
    """Rows ``(label, model_hz, measured_hz, error_percent)`` against the measured modes.

    ``measured`` defaults to the rig file's ``measured_modes_hz`` (the thesis: 0, 0.396,
    1.781 Hz); a rig without them gives no rows.  The rigid-body row takes the 0 Hz mode if
    the variant has one (no relative error), the others take the lowest *oscillatory* modes.
    """
    if measured is None:
        measured = get_model(result.rig or result.model).spec.extra.get("measured_modes_hz", ())
    rows = []
    osc = [f for f, o in zip(result.freq_hz, result.oscillatory) if o]
    k = 0
    for mhz in measured:
        if mhz == 0.0:
            rigid = [f for f, o in zip(result.freq_hz, result.oscillatory) if f == 0.0]
            rows.append(("rigid body", rigid[0] if rigid else float("nan"), 0.0, float("nan")))
            continue
        f = osc[k] if k < len(osc) else float("nan")
        k += 1
        rows.append((f"mode {k}", f, mhz, 100.0 * (f - mhz) / mhz))
    return rows


# ----------------------------------------------------------------------------- stick-slip period
def stick_slip_frequency(model, params: ParameterSet | None = None) -> float:
    """The rig's stick-slip frequency estimate [Hz]: the lowest torsional mode of its mechanical
    chain (damped, no friction) with the boundary condition its drive puts on the top of the string
    (:attr:`models.rig.drives.Drive.boundary`).

    - A drive that holds a speed (a DC motor under its PI loop, a prescribed speed) clamps the top:
      its speed loop is far stiffer than the string, so the string winds up against a held end
      (``"clamped"``).  rig3: 0.4285 Hz, 2.33 s; its stick-slip cycle at 30 rpm and 20 N is 2.3 s.
    - A torque drive leaves the top free: the drive body turns with the string, its own inertia in
      the chain (``"free"``).  The field string (Navarro-Lopez & Cortes 2007): 7.19 s, where its
      limit cycle from rest under 10 kN m is 8.3 s; held at the top it would be 15.7 s.

    The limit cycle is longer than the mode by its stick phase; the mode is its lower bound and the
    time scale of the slip.  ``ConfigError`` when the chain has no oscillatory mode.
    """
    model = get_model(model)
    params = params_of(model, params)
    r = modes(model, params, model.drive.boundary, damped=True)
    osc = [f for f, o in zip(r.freq_hz, r.oscillatory) if o and f > 0]
    if not osc:
        held = "with its drive held" if model.drive.boundary == "clamped" else "with its drive free"
        raise ConfigError(f"rig {model.name!r} has no torsional mode {held}")
    return float(osc[0])


def stick_slip_period(model, params: ParameterSet | None = None) -> float:
    """The rig's stick-slip period estimate [s], ``1 / stick_slip_frequency`` (:func:`stick_slip_frequency`)."""
    return 1.0 / stick_slip_frequency(model, params)
