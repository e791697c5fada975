"""Linearised modal analysis of the rigs about steady sliding.

Three questions are answered here:

1. *Which torsional modes does the rig have?*  :func:`modes` gives natural
   frequencies, damping ratios and mode shapes for

   - ``"free"``: the mechanical chain only (J1, J2, J3 = eta^2 Jm, k1, k2, d1, d2; no
     motor electrics, no friction), i.e. the thesis eq. (3-3) model plus the shaft
     damping; it has the rigid-body 0 Hz mode of eq. (3-4);
   - ``"clamped"``: the same chain with the motor end held fixed (theta3 = 0);
   - ``"closed"``: the full model (rig3: DC motor, PI speed loop, pin friction)
     linearised at steady sliding (:func:`linearise`).

   :func:`compare_measured` sets them against the frequencies the thesis measured
   (Fig. 3.7: 0, 0.396 and 1.781 Hz).
2. *Is steady sliding stable?*  :func:`sliding_stability` returns the largest real
   part of the linearisation; :func:`stability_map` maps it over (N1, speed).  A
   positive value means the negative slope of the Stribeck law beats the damping
   and the rig falls into stick-slip from any small disturbance.
3. *What linear model do controllers/observers see?*  :class:`LinearModel` carries
   A, B, C, D and a python-control ``StateSpace``.

Regularisation
--------------
:func:`linearise` differentiates the regularised model ``model.ode(eps)``.  Its friction
torque is ``tanh(v/eps) T(|v|)``, whose slope is ``T(|v|) sech^2(v/eps)/eps + tanh(v/eps)
T'(|v|)``.  At a sliding speed ``|v| >> eps`` the first term vanishes (``sech^2`` is
below 1e-20 for ``|v| > 25 eps``) and the slope is the Stribeck slope ``T'(|v|)``, i.e.
the linearisation is physically the sliding one.  **eps must therefore be much smaller
than the sliding speed**; :func:`linearise` flags operating points with
``|v| < 10 eps`` in ``status``.

References
----------
thesis Ch. 3, eqs. (3-3)-(3-7), (3-9), (3-13), Fig. 3.7.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
import scipy.linalg

from models.errors import ConfigError
from models.params import ParameterSet, Rig3Params
from models.rigs import RigModel, get_model

__all__ = [
    "LinearModel",
    "ModalResult",
    "MEASURED_HZ",
    "VARIANTS",
    "linearise",
    "operating_point",
    "chain_matrices",
    "modes",
    "compare_measured",
    "sliding_stability",
    "stability_map",
    "stribeck_onset_n1",
]

#: Natural frequencies measured on the 3-disc rig [Hz] (thesis Fig. 3.7, Sect. 3.1.2 and 3.3).
MEASURED_HZ: tuple[float, float, float] = (0.0, 0.396, 1.781)

#: Modal variants: mechanical chain free / clamped at the motor, or the full closed loop.
VARIANTS = ("free", "clamped", "closed")


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class LinearModel:
    """A linearisation ``dx = A dx + B du``, ``dy = C dx + D du`` about ``(x_op, u_op)``.

    Attributes
    ----------
    A, B, C, D : numpy arrays (nx, nx), (nx, nu), (ny, nx), (ny, nu), SI units of the states
    x_op, u_op : operating point (state, input)
    states, inputs, outputs : names
    eps : regularisation of the friction used [rad/s]
    ss : the same system as a python-control ``StateSpace`` (property, built on first use)
    status : human-readable message; success : True if ``x_op`` is an equilibrium
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
    status: str = "ok"
    success: bool = True

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
class ModalResult:
    """Modes of one variant of a model.

    Attributes
    ----------
    model, variant : which system
    freq_hz : (m,) undamped natural frequency |lambda|/(2 pi) of each mode [Hz]
        (0 for the rigid-body mode)
    damped_hz : (m,) damped frequency |Im lambda|/(2 pi) [Hz] (0: non-oscillatory)
    damping : (m,) damping ratio -Re(lambda)/|lambda| (0 for the rigid-body mode;
        negative: an unstable mode)
    oscillatory : (m,) bool, complex pair
    shapes : (m, ndof) real mode shapes on ``dof_names``, normalised so the component of
        largest magnitude is +1 (complex eigenvectors rotated to that component)
    dof_names : the degrees of freedom of ``shapes`` (angles for the mechanical chain,
        speeds for the closed loop)
    eigenvalues : (n,) all eigenvalues [1/s], sorted by magnitude
    max_real : largest real part [1/s] (excluding the rigid-body zero pair)
    status : human-readable message; success : bool
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
    status: str = "ok"
    success: bool = True


# ----------------------------------------------------------------------------- linearisation
def operating_point(model: RigModel, params: ParameterSet, *, omega: float | None = None,
                    load: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Default sliding operating point ``(u, x_op or None)`` of a model.

    Parameters
    ----------
    omega : sliding speed [rad/s] (rig3: omega_ref, disc side; disc: omega3;
        leadscrew: omega_drive; rig2: disc speed).  Defaults: rig3/disc 30 rpm,
        leadscrew 40.3 rad/s (seed 002 Fig. 9.23), rig2 1 rad/s.
    load : normal/axial load (rig3/disc: N1 [N], default 20; leadscrew: R [N], default
        314.3); unused for rig2.

    Returns
    -------
    u : input vector; x_op : the equilibrium state when it is known in closed form
        (rig2, whose pure-Coulomb sliding is a continuum of equilibria), else None.
    """
    name = model.name
    if name == "rig3":
        w = math.pi if omega is None else float(omega)
        return np.array([w, 20.0 if load is None else float(load), 0.0]), None
    if name == "disc":
        w = math.pi if omega is None else float(omega)
        return np.array([w, 20.0 if load is None else float(load)]), None
    if name == "leadscrew":
        w = 40.3 if omega is None else float(omega)
        return np.array([w, 314.3 if load is None else float(load)]), None
    if name == "rig2":
        p = params
        w = 1.0 if omega is None else float(omega)
        Tfric = np.sign(w) * (p.Tc + (p.Ts - p.Tc) * math.exp(-abs(w) / p.v_s))
        tau = Tfric + (p.cd + p.cm) * w
        x = np.array([-(Tfric + p.cd * w) / p.k, w, w])
        return np.array([tau]), x
    raise ConfigError(f"no operating point defined for model {name!r}")


_FUNCS: dict = {}


def _functions(model: RigModel, eps: float, outputs: tuple[str, ...]):
    """(ode, Newton equilibrium solver g(x; u, p), Jacobian Function), cached per model/eps/outputs."""
    key = (model.name, eps, outputs)
    if key not in _FUNCS:
        f = model.ode(eps)
        x, uu, p = ca.SX.sym("x", model.nx), ca.SX.sym("u", model.nu), ca.SX.sym("p", model.n_p)
        xd = f(x, uu, p)
        g = ca.Function("g", [x, ca.vertcat(uu, p)], [xd])
        solver = ca.rootfinder("eq", "newton", g, {"abstol": 1e-12, "max_iter": 100})
        y = model.meas_vector(list(outputs))(x, uu, p)
        jac = ca.Function(f"{model.name}_lin", [x, uu, p],
                          [ca.jacobian(xd, x), ca.jacobian(xd, uu), ca.jacobian(y, x), ca.jacobian(y, uu), xd],
                          ["x", "u", "p"], ["A", "B", "C", "D", "xdot"])
        _FUNCS[key] = (f, solver, jac)
    return _FUNCS[key]


def linearise(model: RigModel | str, params: ParameterSet, u, eps: float | None = None,
              x_op=None, outputs: tuple[str, ...] | None = None) -> LinearModel:
    """Linearise the regularised model about steady sliding.

    Parameters
    ----------
    model : a rig model (or its name)
    params : its parameter set (published or fitted)
    u : (nu,) constant input of the operating point (e.g. rig3: omega_ref [rad/s], N1, N2 [N])
    eps : friction regularisation [rad/s]; must be << the sliding speed (module docstring)
    x_op : (nx,) operating state; default: the equilibrium of ``model.ode(eps)`` at ``u``
        (Newton from ``model.sliding_guess``)
    outputs : output names (default: every output of ``model.outputs`` that needs no
        absolute angle)

    Returns
    -------
    LinearModel
        ``success`` is False if ``x_op`` is not an equilibrium (|f| > 1e-8) or the
        sliding speed is not >> eps.

    References
    ----------
    CasADi ``jacobian`` of the named Function ``model.ode(eps)``.
    """
    model = get_model(model) if isinstance(model, str) else model
    if not isinstance(params, model.param_cls):
        raise ConfigError(f"params must be {model.param_cls.__name__} for model {model.name!r}, "
                          f"got {type(params).__name__}")
    u = np.asarray(u, dtype=float).ravel()
    if u.shape != (model.nu,) or not np.all(np.isfinite(u)):
        raise ConfigError(f"u must be {model.nu} finite numbers {model.inputs}, got {u}")
    eps = model.eps_default if eps is None else float(eps)
    if not eps > 0:
        raise ConfigError(f"eps must be > 0 rad/s, got {eps}")
    if outputs is None:
        outputs = tuple(n for n in model.output_names() if not n.startswith("theta"))
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
                       model.name, "; ".join(msgs) or "ok", not msgs)


# ----------------------------------------------------------------------------- mechanical chain
def chain_matrices(params: Rig3Params, *, clamped: bool = False, damped: bool = True):
    """Mass, damping and stiffness matrices of the 3-disc chain (thesis eq. 3-3).

    Parameters
    ----------
    params : Rig3Params (J1, J2, Jm, eta, k1, k2, d1, d2 used)
    clamped : hold the motor end (theta3 = 0): 2 DOF (theta1, theta2)
    damped : include the shaft damping d1, d2 (eq. 3-3 itself is undamped)

    Returns
    -------
    M, Cd, K : (n, n) arrays [kg m^2], [N m s/rad], [N m/rad]; dof names
    """
    p = params
    M = np.diag([p.J1, p.J2, p.eta ** 2 * p.Jm])
    K = np.array([[p.k1, -p.k1, 0.0], [-p.k1, p.k1 + p.k2, -p.k2], [0.0, -p.k2, p.k2]])
    d1, d2 = (p.d1, p.d2) if damped else (0.0, 0.0)
    Cd = np.array([[d1, -d1, 0.0], [-d1, d1 + d2, -d2], [0.0, -d2, d2]])
    dofs = ("theta1", "theta2", "theta3")
    if clamped:
        return M[:2, :2], Cd[:2, :2], K[:2, :2], dofs[:2]
    return M, Cd, K, dofs


def _second_order_ss(M, Cd, K) -> np.ndarray:
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ Cd]])


def _modes_from_A(A: np.ndarray, dof_index: list[int], dof_names, model: str, variant: str,
                  zero_tol: float = 1e-6) -> ModalResult:
    """One mode per complex pair (Im > 0) and per real eigenvalue; the zero cluster is one
    rigid-body mode."""
    lam, V = scipy.linalg.eig(A)
    order = np.argsort(np.abs(lam), kind="stable")
    lam, V = lam[order], V[:, order]
    scale = max(1.0, float(np.max(np.abs(lam))))
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
        model, variant,
        np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
        np.array([r[3] for r in rows], dtype=bool), np.array([r[4] for r in rows]), tuple(dof_names),
        lam, max_real, "ok" if ok else "non-finite eigenvalues", ok)


def modes(model: RigModel | str = "rig3", params: ParameterSet | None = None, variant: str = "closed", *,
          u=None, omega: float | None = None, load: float | None = None, eps: float | None = None,
          damped: bool = True) -> ModalResult:
    """Natural frequencies, damping ratios and mode shapes of one variant.

    Parameters
    ----------
    model : "rig3", "rig2", "leadscrew" or "disc" (or the model object)
    params : parameter set (default: published)
    variant : "free" | "clamped" (rig3 mechanical chain) or "closed" (any model:
        linearised at steady sliding; "sliding" is accepted as the same)
    u : input of the operating point (closed); default from :func:`operating_point`
        with ``omega`` [rad/s] and ``load`` (N1 [N] or R [N])
    eps : regularisation for the closed variant [rad/s]
    damped : include d1, d2 in the mechanical chain (free/clamped)

    Returns
    -------
    ModalResult
    """
    model = get_model(model) if isinstance(model, str) else model
    params = model.published() if params is None else params
    if variant == "sliding":
        variant = "closed"
    if variant not in VARIANTS:
        raise ConfigError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if variant in ("free", "clamped"):
        if model.name != "rig3":
            raise ConfigError(f"variant {variant!r} is defined for model 'rig3' only, got {model.name!r}")
        M, Cd, K, dofs = chain_matrices(params, clamped=(variant == "clamped"), damped=damped)
        A = _second_order_ss(M, Cd, K)
        return _modes_from_A(A, list(range(len(dofs))), dofs, model.name, variant)
    if u is None:
        u, x_op = operating_point(model, params, omega=omega, load=load)
    else:
        x_op = None
    lin = linearise(model, params, u, eps=eps, x_op=x_op)
    speed_idx = [i for i, s in enumerate(model.states) if s.startswith("omega")]
    res = _modes_from_A(lin.A, speed_idx, [model.states[i] for i in speed_idx], model.name, "closed")
    if not lin.success:
        res = ModalResult(**{**res.__dict__, "status": lin.status, "success": False})
    return res


def compare_measured(result: ModalResult, measured=MEASURED_HZ) -> list[tuple[str, float, float, float]]:
    """Rows ``(label, model_hz, measured_hz, error_percent)`` against the thesis' modes.

    The rigid-body row takes the 0 Hz mode if the variant has one (error reported as the
    absolute value in Hz, since 0 has no relative error), else NaN; the two flexible rows
    take the two lowest *oscillatory* modes (undamped natural frequency).
    """
    rows = []
    rigid = [f for f, o in zip(result.freq_hz, result.oscillatory) if f == 0.0]
    rows.append(("rigid body", rigid[0] if rigid else float("nan"), measured[0], float("nan")))
    osc = [f for f, o in zip(result.freq_hz, result.oscillatory) if o]
    for k, label in enumerate(("mode 1", "mode 2")):
        f = osc[k] if k < len(osc) else float("nan")
        rows.append((label, f, measured[k + 1], 100.0 * (f - measured[k + 1]) / measured[k + 1]))
    return rows


# ----------------------------------------------------------------------------- stability of sliding
def sliding_stability(model: RigModel | str, params: ParameterSet, u, eps: float | None = None,
                      x_op=None) -> tuple[bool, float]:
    """Is steady sliding at input ``u`` linearly stable?

    Returns
    -------
    stable : bool (largest real part < 0)
    max_real : largest real part of the eigenvalues [1/s]
    """
    lin = linearise(model, params, u, eps=eps, x_op=x_op)
    mr = float(np.max(np.linalg.eigvals(lin.A).real))
    return bool(mr < 0.0), mr


def stability_map(model: RigModel | str, params: ParameterSet, n1_values, omega_values,
                  eps: float | None = None) -> np.ndarray:
    """Largest real part [1/s] of the sliding linearisation over (N1, speed).

    Parameters
    ----------
    model : "rig3" or "disc" (inputs (speed, N1, ...) with the remaining ones zero)
    n1_values : (a,) pin force N1 [N]; omega_values : (b,) sliding speed [rad/s]

    Returns
    -------
    (a, b) array; > 0 where steady sliding is unstable (stick-slip onset).
    """
    model = get_model(model) if isinstance(model, str) else model
    if model.name not in ("rig3", "disc"):
        raise ConfigError(f"stability_map supports 'rig3' and 'disc', got {model.name!r}")
    n1_values = np.asarray(n1_values, dtype=float).ravel()
    omega_values = np.asarray(omega_values, dtype=float).ravel()
    out = np.empty((n1_values.size, omega_values.size))
    for a, n1 in enumerate(n1_values):
        for b, w in enumerate(omega_values):
            u = np.zeros(model.nu)
            u[0], u[1] = w, n1
            out[a, b] = sliding_stability(model, params, u, eps=eps)[1]
    return out


def stribeck_onset_n1(params, omega: float, damping: float) -> float:
    """Pin force at which the Stribeck slope cancels a viscous damping (single-DOF estimate).

    The friction torque's slope at sliding speed ``omega`` is
    ``-N r (mu_s - mu_k) exp(-omega/v_s) / v_s``; steady sliding of one disc on a damped
    spring loses stability when this negative damping exceeds ``damping`` [N m s/rad]:
    ``N* = damping v_s exp(omega/v_s) / (r (mu_s - mu_k))`` [N].
    """
    r = params.r1 if hasattr(params, "r1") else params.r
    return damping * params.v_s * math.exp(omega / params.v_s) / (r * (params.mu_s - params.mu_k))
