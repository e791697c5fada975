"""Fixed-step discretisation for optimisers: RK4 with substeps, zero-order-hold input.

The regularised friction makes the model stiff near zero speed (rate about
``N r mu / (eps J)``), so explicit RK4 needs substeps; see ``shared/CASADI-FACTS.md``.
"""

from __future__ import annotations

import casadi as ca

from models.errors import ConfigError

__all__ = ["rk4", "rk4_function"]


def rk4(f, x, u, p, h, nsub: int):
    """``nsub`` RK4 steps of size ``h/nsub`` of ``xdot = f(x, u, p)`` (symbolic or numeric)."""
    hs = h / nsub
    for _ in range(nsub):
        k1 = f(x, u, p)
        k2 = f(x + hs / 2 * k1, u, p)
        k3 = f(x + hs / 2 * k2, u, p)
        k4 = f(x + hs * k3, u, p)
        x = x + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def rk4_function(model, dt: float, nsub: int, eps: float | None = None, *, name: str | None = None,
                 expand: bool = True) -> ca.Function:
    """Discrete-time model ``x+ = F(x, u, p)`` over ``dt`` [s] with ``nsub`` RK4 substeps.

    Parameters
    ----------
    model : models.rig.RigModel
    dt : sample period [s], > 0
    nsub : substeps per sample, >= 1
    eps : friction regularisation [rad/s] (model default if None)
    expand : build in SX (fast to evaluate, good for Jacobians) instead of MX
    """
    if not dt > 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    if int(nsub) != nsub or nsub < 1:
        raise ConfigError(f"nsub must be an integer >= 1, got {nsub}")
    f = model.ode(eps)
    kind = ca.SX if expand else ca.MX
    x = kind.sym("x", model.nx)
    u = kind.sym("u", model.nu)
    p = kind.sym("p", model.n_p)
    xn = rk4(lambda a, b, c: f(a, b, c), x, u, p, dt, int(nsub))
    return ca.Function(name or f"{model.cname}_rk4", [x, u, p], [xn], ["x", "u", "p"], ["x_next"])
