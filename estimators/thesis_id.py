"""The thesis' own identification of the 3-disc rig, reproduced from its printed raw data.

Each function recomputes one step of thesis Sect. 3.1.2 (``shared/reference/000_*.txt``)
from the numbers printed there and returns what it finds; ``tests/test_thesis_id.py``
compares them with the printed results and records the differences.

- :func:`static_stiffness` -- Table 3.3, eq. (3-2) (Hooke's law per weight, then the mean).
  Row 3 of the k1 table is garbled in the source (k1_3 missing); it is recomputed as
  torque/angle = 1.0021/0.8105 = 1.2364, which reproduces the printed mean 1.2566.
- :func:`modal_stiffness` -- eq. (3-6): the stiffnesses whose undamped 3-DOF eigenvalues
  (eq. 3-3, J3 = eta^2 Jm) equal the measured ``omega_n^2``, solved with
  ``scipy.optimize.root(method="hybr")`` (MINPACK's modified Powell hybrid method, as in the
  thesis) from the static means.  FINDING: this does NOT give the printed k1 = 1.1175,
  k2 = 0.3659; see the function's notes.
- :func:`log_decrement` / :func:`damping` -- eqs. (3-8), (3-9).  FINDING: the printed
  d1 = 0.02145 follows from the STATIC mean k1 = 1.2566, not from eq. (3-7)'s 1.1175.
- :func:`static_friction` -- eq. (3-10) and Table 3.5.
- :func:`simulate_spin_down` / :func:`fit_kinetic_friction` -- eqs. (3-12), (3-13): a disc loose
  from the string decelerated by the pin; the spin-down is SIMULATED (the thesis' data are
  not printed), measured with a 1000-tick encoder at 10 ms, and mu_k is fitted by
  ``scipy.optimize.least_squares``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares, root

from models.errors import ConfigError
from models.params import ParameterSet
from models.status import Outcome, Status
from models.rig import published

__all__ = [
    "G", "D1", "D2", "TABLE_3_3_K1", "TABLE_3_3_K2", "TABLE_3_4", "TABLE_3_5", "OMEGA_N",
    "static_stiffness", "modal_eigenvalues", "modal_stiffness", "log_decrement", "damping",
    "static_friction", "SpinDown", "simulate_spin_down", "fit_kinetic_friction", "d2_candidates",
]

G = 9.81          # m/s^2, thesis eq. (3-2)
D1 = 0.190        # m, thesis Table 3.2
D2 = 0.162        # m, thesis Table 3.2
R1 = 0.047        # m, thesis eq. (3-10)

#: thesis Table 3.3, (torque [N m], delta12 [rad], k1 printed [N m/rad] or None if garbled)
TABLE_3_3_K1 = ((0.9286, 0.6409, 1.4489), (0.9554, 0.7140, 1.3381), (1.0021, 0.8105, None),
                (1.0485, 0.8859, 1.1835), (1.0952, 1.0179, 1.0759))
TABLE_3_3_K1_MEAN = 1.2566
#: thesis Table 3.3, (torque [N m], delta23 [rad], k2 printed [N m/rad])
TABLE_3_3_K2 = ((0.0398, 0.1257, 0.3168), (0.0795, 0.2262, 0.3516), (0.1611, 0.4932, 0.3267),
                (0.3980, 1.0681, 0.3726), (0.4874, 1.3226, 0.3685))
TABLE_3_3_K2_MEAN = 0.3473
#: thesis Table 3.4: damping ratios xi_1j, xi_2j and the printed means
TABLE_3_4 = ((0.05698, 0.05574), (0.05817, 0.05418), (0.05351, 0.05266))
TABLE_3_4_MEAN = (0.05622, 0.05419)
#: thesis Table 3.5: three blocks of (N1 [N], F_T [N], mu_s printed)
TABLE_3_5 = (
    ((6.10, 1.40, 0.4639), (6.15, 1.55, 0.5094), (6.00, 1.50, 0.5053), (6.20, 1.60, 0.5216), (6.15, 1.55, 0.5094)),
    ((9.50, 2.30, 0.4894), (9.55, 2.40, 0.5080), (9.50, 2.40, 0.5106), (9.40, 2.25, 0.4838), (9.65, 2.35, 0.4922)),
    ((15.70, 3.90, 0.5021), (15.65, 3.85, 0.4972), (15.60, 3.80, 0.4924), (15.70, 3.95, 0.5085), (15.75, 3.80, 0.4877)),
)
TABLE_3_5_MEANS = (0.5019, 0.4968, 0.4976)
#: thesis Sect. 3.1.2 (Fig. 3.7): measured natural frequencies [rad/s]
OMEGA_N = (0.396 * 2 * math.pi, 1.781 * 2 * math.pi)


def static_stiffness() -> dict:
    """Table 3.3 recomputed: per-test stiffness torque/angle and the means [N m/rad].

    Returns ``{"k1": (5,), "k2": (5,), "k1_mean", "k2_mean"}``.
    """
    k1 = np.array([tq / d for tq, d, _ in TABLE_3_3_K1])
    k2 = np.array([tq / d for tq, d, _ in TABLE_3_3_K2])
    return {"k1": k1, "k2": k2, "k1_mean": float(k1.mean()), "k2_mean": float(k2.mean())}


def modal_eigenvalues(k1: float, k2: float, J1: float, J2: float, J3: float) -> np.ndarray:
    """The two non-zero eigenvalues ``omega^2`` [rad^2/s^2] of eq. (3-3), ascending.

    ``J3 = inf`` (``math.inf``) clamps the third inertia (motor held by its gearbox).
    """
    if math.isinf(J3):
        M = np.diag([J1, J2])
        K = np.array([[k1, -k1], [-k1, k1 + k2]])
        return np.sort(np.linalg.eigvals(np.linalg.solve(M, K)).real)
    M = np.diag([J1, J2, J3])
    K = np.array([[k1, -k1, 0.0], [-k1, k1 + k2, -k2], [0.0, -k2, k2]])
    lam = np.sort(np.linalg.eigvals(np.linalg.solve(M, K)).real)
    return lam[1:]  # drop the rigid-body root lambda = 0 (eq. 3-4)


@dataclass(frozen=True)
class ModalFit(Outcome):
    """Result of :func:`modal_stiffness`: k1, k2 [N m/rad], residual, solver status."""

    k1: float
    k2: float
    residual: np.ndarray
    frequencies_hz: np.ndarray
    status: Status
    message: str
    variant: str


def modal_stiffness(x0=None, *, omega_n=OMEGA_N, params: ParameterSet | None = None, motor: str = "free") -> ModalFit:
    """Eq. (3-6): solve ``omega_n_i^2 - lambda_i(k1, k2) = 0`` with MINPACK's modified Powell method.

    Parameters
    ----------
    x0 : initial (k1, k2); default the Table 3.3 means (as in the thesis)
    omega_n : measured natural frequencies [rad/s]
    params : the rig3 set with the inertias J1, J2 and J3 = eta^2 Jm (default: the published one)
    motor : "free" (eq. 3-3 as printed, J3 = eta^2 Jm) or "clamped" (J3 -> inf)

    Notes
    -----
    With eq. (3-3) as printed the solution is k1 = 1.189, k2 = 0.0988 N m/rad, not the
    printed 1.1175 / 0.3659: the printed pair gives 0.717 and 1.836 Hz, far from the
    measured 0.396 Hz.  Clamping the motor end gives k1 = 1.093, k2 = 0.306 (2 % and 16 %
    from the printed values).  Neither reproduces eq. (3-7); the thesis does not print
    enough to tell which inertias it used.
    """
    if motor not in ("free", "clamped"):
        raise ConfigError(f"motor must be 'free' or 'clamped', got {motor!r}")
    st = static_stiffness()
    x0 = np.array([st["k1_mean"], st["k2_mean"]] if x0 is None else x0, dtype=float)
    params = published("rig3") if params is None else params
    J3 = math.inf if motor == "clamped" else params.eta ** 2 * params.Jm
    target = np.asarray(omega_n, dtype=float) ** 2

    def f(k):
        return target - modal_eigenvalues(k[0], k[1], params.J1, params.J2, J3)

    sol = root(f, x0, method="hybr")
    lam = modal_eigenvalues(sol.x[0], sol.x[1], params.J1, params.J2, J3)
    return ModalFit(float(sol.x[0]), float(sol.x[1]), np.asarray(sol.fun), np.sqrt(np.abs(lam)) / (2 * math.pi),
                    Status.OK if sol.success else Status.NOT_CONVERGED, str(sol.message), motor)


def log_decrement(x_j: float, x_j1: float) -> float:
    """Damping ratio from two successive peaks, eq. (3-8)."""
    if not (x_j > x_j1 > 0):
        raise ConfigError(f"peaks must satisfy x_j > x_j+1 > 0, got {x_j}, {x_j1}")
    delta = math.log(x_j / x_j1)
    return 1.0 / math.sqrt(1.0 + (2 * math.pi / delta) ** 2)


def damping(k1: float, k2: float, xi=TABLE_3_4_MEAN, J1: float = 0.02888, J2: float = 0.01496) -> tuple[float, float]:
    """Eq. (3-9): ``d1 = 2 xi1 sqrt(k1 J1)``, ``d2 = 2 xi2 sqrt((k1 + k2) J2)`` [N m s/rad]."""
    return 2 * xi[0] * math.sqrt(k1 * J1), 2 * xi[1] * math.sqrt((k1 + k2) * J2)


def d2_candidates(d2_printed: float = 0.01595, J2: float = 0.01496) -> dict:
    """What reproduces the printed d2: the stiffness sum for xi2 = 0.05419, or the xi for k1 + k2 of eq. (3-7)."""
    ksum = (d2_printed / (2 * TABLE_3_4_MEAN[1])) ** 2 / J2
    xi = d2_printed / (2 * math.sqrt((1.1175 + 0.3659) * J2))
    return {"k_sum_for_mean_xi2": ksum, "xi_for_eq_3_7": xi}


def static_friction() -> dict:
    """Eq. (3-10) on Table 3.5: ``mu_s = F_T (D1/2) / (N1 r1)`` per trial, block means, overall (3-11)."""
    blocks = [np.array([ft * (D1 / 2) / (n * R1) for n, ft, _ in blk]) for blk in TABLE_3_5]
    means = np.array([b.mean() for b in blocks])
    return {"trials": blocks, "block_means": means, "mu_s": float(means.mean())}


# --------------------------------------------------------------------------- mu_k by spin-down
@dataclass(frozen=True)
class SpinDown:
    """A (simulated) spin-down record: times [s], measured angle [rad] and speed [rad/s]."""

    t: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    omega_true: np.ndarray
    n1: float
    mu_k_true: float


def simulate_spin_down(mu_k: float = 0.306, *, mu_s: float = 0.5, n1: float = 10.0, omega0: float = 8.0,
                       J1: float = 0.02888, r1: float = R1, v_s: float = 1.0, dt: float = 0.01,
                       ticks_per_rev: int = 1000, seed: int = 0) -> SpinDown:
    """Disc R1 loose from the string, decelerated by the pin: ``J1 w' = -T_r1(w)`` (3-12, 3-13).

    The exact ODE is integrated (``solve_ivp``, stops when the disc stops) and sampled by a
    quantised incremental encoder (``ticks_per_rev``, random initial tick phase from ``seed``);
    the speed is the backward difference of the angle, as on the rig.
    """
    if not omega0 > 0:
        raise ConfigError(f"omega0 must be > 0 rad/s, got {omega0}")

    def rhs(t, y):
        w = max(y[1], 0.0)
        return [y[1], -n1 * r1 * (mu_k + (mu_s - mu_k) * math.exp(-abs(w) / v_s)) / J1]

    def stop(t, y):
        return y[1]
    stop.terminal = True
    stop.direction = -1
    sol = solve_ivp(rhs, (0, 100.0), [0.0, omega0], events=stop, rtol=1e-10, atol=1e-12, dense_output=True)
    t_end = sol.t[-1]
    t = np.arange(0.0, t_end, dt)
    Y = sol.sol(t)
    q = 2 * math.pi / ticks_per_rev
    phase = np.random.default_rng(seed).uniform(0, q)
    theta = np.floor((Y[0] + phase) / q) * q
    omega = np.r_[omega0, np.diff(theta) / dt]
    return SpinDown(t, theta, omega, Y[1], n1, mu_k)


@dataclass(frozen=True)
class KineticFit(Outcome):
    """mu_k by least squares; ``method`` "equation" (thesis: J1 a + T_r = 0) or "output" (fit w(t))."""

    mu_k: float
    stderr: float
    method: str
    status: Status
    message: str


def fit_kinetic_friction(rec: SpinDown, *, method: str = "equation", mu_s: float = 0.5, J1: float = 0.02888,
                         r1: float = R1, v_s: float = 1.0, min_speed: float = 0.5) -> KineticFit:
    """Fit mu_k to a spin-down with ``scipy.optimize.least_squares``.

    ``method="equation"`` is the thesis' way: the acceleration from a discrete derivative of
    the (backward-difference) speed, central differences, and the residual of eq. (3-12),
    ``J1 a + N1 r1 [mu_k + (mu_s - mu_k) exp(-|w|)]``, over samples faster than
    ``min_speed``.  ``method="output"`` integrates (3-12) and fits the measured speed.
    """
    t, w = rec.t, rec.omega
    if method == "equation":
        # speed at mid-interval from the backward differences; acceleration by central differences
        wm = w[1:]
        tm = t[1:] - 0.5 * (t[1] - t[0])
        a = np.gradient(wm, tm)
        mask = wm > min_speed

        def res(x):
            mk = x[0]
            return J1 * a[mask] + rec.n1 * r1 * (mk + (mu_s - mk) * np.exp(-np.abs(wm[mask]) / v_s))
    elif method == "output":
        mask = w > min_speed

        def res(x):
            mk = x[0]
            sol = solve_ivp(lambda tt, y: [-rec.n1 * r1 * (mk + (mu_s - mk) * math.exp(-abs(max(y[0], 0)) / v_s)) / J1],
                            (t[0], t[-1]), [w[0]], t_eval=t, rtol=1e-8, atol=1e-10)
            ws = np.full(t.shape, np.nan)
            ws[:sol.y.shape[1]] = sol.y[0]
            # the measured speed is the mean over the preceding sample: compare at mid-interval
            wmid = np.r_[ws[0], 0.5 * (ws[1:] + ws[:-1])]
            return np.nan_to_num(wmid[mask] - w[mask], nan=10.0)
    else:
        raise ConfigError(f"method must be 'equation' or 'output', got {method!r}")
    sol = least_squares(res, [0.3], bounds=([0.0], [mu_s]))
    r = sol.fun
    Jm = sol.jac
    dof = max(r.size - 1, 1)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(Jm.T @ Jm)
    return KineticFit(float(sol.x[0]), float(math.sqrt(max(cov[0, 0], 0.0))), method,
                      Status.OK if sol.success else Status.NOT_CONVERGED, str(sol.message))
