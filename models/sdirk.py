"""An L-stable implicit step for stiff friction, written as a CasADi expression.

The regularised friction law ``-tanh(v/eps) T(|v|)`` has the rate ``N r mu / (eps J)`` near rest:
at the slow drive speeds of a friction bench (a 30 g slider pulled at 42 um/s, eps = 0.16 % of
that) it reaches 1e7-1e8 1/s, and explicit RK4 would need tens of thousands of substeps per
sample.  An L-stable implicit method damps such a rate in one step whatever ``h lambda``, so the
substep is set by the rates that matter (the springs, a Stribeck fall) instead.

The method: the two-stage, stiffly accurate, L-stable SDIRK of order 2 (R. Alexander, "Diagonally
implicit Runge-Kutta methods for stiff ODEs", SIAM J. Numer. Anal. 14(6), 1977, with
``gamma = 1 - 1/sqrt(2)``; Hairer & Wanner, *Solving ODEs II*, Sect. IV.6)::

    Z1 = x + gamma h f(Z1)
    Z2 = x + (1 - gamma) h k1 + gamma h f(Z2),   k1 = (Z1 - x) / (gamma h)
    x+ = Z2

Each stage is solved by Newton's method with the exact Jacobian, unrolled a fixed number of
times (:data:`NEWTON_ITER`) in the expression graph: the step is plain SX arithmetic (``if_else``,
a dense ``solve`` of the state's size), so it code-generates, maps and differentiates like the
RK4 step; its derivatives with respect to the state, the inputs and the parameters are the
derivatives of the converged Newton iterates, which equal the implicit function theorem's once
the iteration has converged (Gauss-Newton gets the step's true Jacobian).

Newton's method alone fails where a contact's speed crosses zero within a stage: far from rest
the friction's Jacobian is that of a constant (``tanh`` saturated), the first iterate overshoots
to the other side, and the iterates chatter between the two branches.  Each stage therefore starts
from a **predictor** built like the exact stick/slip step (Moreau's time stepping): for every
contact body ``j`` with a memoryless law, the speed it would reach without friction,
``a = v_j + gamma h f_j(v_j = 0)`` (the regularised friction vanishes at rest), and what the
friction takes off it at its peak over the band's edge, ``b = gamma h max_c |f_j(0) - f_j(+-c eps)|``
(c = 1, 2, 4, ... 32), and at the speed ``a``, ``b_a``: where ``|a| <= b`` the contact sticks and
the start is rest (left of the root, where ``r(v) = v - a + gamma h T(v)/J`` is concave: Newton's
iterates climb to the root monotonically); else it slides and the start is the kinetic speed
``sign(a) max(v_peak, |a| - b_a)``, beyond the peak (a start at rest would crawl through the band's
steep part for many iterations; a slide mistaken for a stick or the reverse makes the iterates
cycle between the branches).  Newton's iterates are safeguarded by a bracket of the contact's speed
(rest and the friction-free speed ``a``, narrowed by the residual's sign at each iterate): a step
that leaves it cuts the bracket instead (at rest, or at its ends' geometric mean), which ends the two-branch cycles a predictor on the wrong side of a
breakaway starts (a free speed within 1e-10 of the friction's peak).  The stage equation has exactly one root as long as the substep resolves any
negative slope of the law, ``gamma h |dT/dv| / J < 1``, which the integration rule ensures.

The step is checked against scipy's Radau at tight tolerances and against the exact stick/slip
plant, with its measured convergence order, in ``tests/test_implicit.py``.
"""

from __future__ import annotations

import math

import casadi as ca

__all__ = ["GAMMA", "NEWTON_ITER", "NEWTON_SMOOTH", "sdirk2"]

#: the SDIRK2 diagonal coefficient (L-stable, stiffly accurate, order 2)
GAMMA = 1.0 - 1.0 / math.sqrt(2.0)
#: Newton iterations per stage where a contact's friction switches sign through a regularisation band
#: or is logarithmic in the speed (the predictor and the bracket take up to ~10 near a breakaway at
#: h lambda ~ 1e4-1e5; ``tests/test_implicit.py`` checks the residual along stick-slip runs)
NEWTON_ITER = 12
#: ... and where every law is smooth in the speed (LuGre: converged to round-off in 3)
NEWTON_SMOOTH = 4
#: speeds (in units of the band) at which the predictor looks for the regularised law's peak
_PEAK = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)


def _symbolic(x) -> bool:
    return isinstance(x, (ca.SX, ca.MX))


def _with(x, j: int, value):
    """``x`` with entry ``j`` replaced by ``value`` (a column expression).  Sliced by rows and column:
    a 1x1 expression's ``x[:0]`` is 1x0 (CasADi reads a scalar as a row too), which ``vertcat`` counts."""
    return ca.vertcat(x[:j, 0], value, x[j + 1:, 0])


def _split(lo, hi, floor):
    """Where a bracket of a contact's speed is cut: at rest if it holds rest, else at the geometric mean
    of its ends, neither taken below ``floor`` (a stage's speed spans decades, from a creep far inside
    the band to a slide: halving in the logarithm finds it in a few cuts where halving the interval
    takes tens)."""
    pos = ca.sqrt(ca.fmax(lo, floor) * ca.fmax(hi, floor))
    neg = -ca.sqrt(ca.fmax(-hi, floor) * ca.fmax(-lo, floor))
    return ca.if_else(lo >= 0, pos, ca.if_else(hi <= 0, neg, 0))


def sdirk2(f, x, u, p, h, *, stiff=(), band=None, bracket=(), newton: int = NEWTON_ITER, quad=None,
           residual: bool = False, jac: tuple = ()):
    """One SDIRK2 step of ``xdot = f(x, u, p)`` over ``h`` (symbolic), input held.

    Parameters
    ----------
    f : callable ``(x, u, p) -> xdot`` on CasADi expressions (it may use outer symbols)
    x : (n,) SX or MX column, the state at the start; u, p : whatever ``f`` takes
    h : the step [s] (number or expression)
    stiff : indices of state entries that are contact speeds with a memoryless (sign-like) friction
        law: the predictor's Moreau start is used for them (module docstring)
    band : the width [rad/s] of those laws' regularisation (eps); required with ``stiff``
    bracket : indices of further contact speeds whose friction vanishes at rest whatever the law's
        states (rate-and-state's arcsinh form): no predictor, but their Newton iterates are kept
        between rest and the friction-free speed as ``stiff`` ones are
    newton : Newton iterations per stage
    quad : optional callable ``(x, u, p) -> g``: also return ``int g dt`` over the step by the method's
        quadrature (``h ((1 - gamma) g(Z1) + gamma g(Z2))``)
    residual : also return the largest stage residual ``|Z - base - gamma h f(Z)|`` after the iterations
    jac : names among ``"x"``, ``"u"``, ``"p"`` (each argument a pure symbol): also return
        ``d x_next / d arg`` for each, by the implicit function theorem at the last iterates
        (:func:`_ift_jacobians`), not by differentiating the unrolled Newton iterations: the same
        matrix once they have converged, at the cost of one Newton iteration instead of twelve
        differentiated (an NMPC stage on a stiff DC-motor rig: 864,569 SX instructions, 23 MB of C
        that gcc -O2 did not finish in 17 minutes)

    Returns
    -------
    x_next, or ``(x_next, q)`` with ``quad``, with the residual appended when asked, then the
    Jacobians asked in ``jac``
    """
    kind = ca.MX if isinstance(x, ca.MX) else ca.SX
    n = x.numel()
    zs = kind.sym("z", n)
    fz = f(zs, u, p)
    jz = ca.jacobian(fz, zs)
    gh = GAMMA * h

    def f_at(z):
        return ca.substitute(fz, zs, z)

    def newton_stage(base, xk):
        z = base + gh * f_at(xk)
        brackets, floors, logs = {}, {}, set(bracket)
        for j in bracket:
            # start from the friction-free speed: the far end of the bracket, from which Newton's iterates
            # on the (logarithmic in the speed, convex in its logarithm) residual descend monotonically
            a = base[j] + gh * f_at(_with(xk, j, 0))[j]
            pad = 0.1 * ca.fabs(a)
            brackets[j] = [ca.fmin(0, a) - pad, ca.fmax(0, a) + pad]
            floors[j] = 1e-12 * ca.fabs(a) + 1e-300
            z = _with(z, j, a)
        if stiff:
            guess = {}
            for j in stiff:
                f0 = f_at(_with(xk, j, 0))[j]
                a = base[j] + gh * f0
                sa = ca.if_else(a >= 0, 1, -1)
                # the most the friction can take off: its peak over the band's edge (the regularised law
                # rises through the band and may fall beyond it), at the speed of that peak
                b_peak, v_peak = -ca.inf, 0
                for c in _PEAK:
                    b = sa * gh * (f0 - f_at(_with(xk, j, sa * c * band))[j])
                    v_peak = ca.if_else(b > b_peak, c * band, v_peak)
                    b_peak = ca.fmax(b_peak, b)
                b_far = sa * gh * (f0 - f_at(_with(xk, j, a))[j])
                # stick (the peak holds it): rest; slide: the kinetic guess, at least the peak's speed
                guess[j] = ca.if_else(sa * a <= b_peak, 0, sa * ca.fmax(v_peak, sa * a - b_far))
                # the stage's speed lies between rest and the friction-free speed (r(0) = -a, r(a) = the
                # friction's impulse, of the sign of a), widened for the other states' small coupling
                pad = 0.1 * ca.fabs(a) + 10 * band
                brackets[j] = [ca.fmin(0, a) - pad, ca.fmax(0, a) + pad]
                floors[j] = 1e-3 * band
            xg = xk
            for j, v in guess.items():
                xg = _with(xg, j, v)
            z = base + gh * f_at(xg)
            for j, v in guess.items():
                z = _with(z, j, v)
        eye = kind.eye(n)
        js = list(brackets)
        cols = kind.zeros(n, len(js))
        for k, j in enumerate(js):
            cols[j, k] = 1
        for _ in range(int(newton)):
            fv, jv = ca.substitute([fz, jz], [zs], [z])
            r = z - base - gh * fv
            if not js:
                z = z - ca.solve(eye - gh * jv, r)
                continue
            sol = ca.solve(eye - gh * jv, ca.horzcat(-r, cols))
            step, w = sol[:, 0], sol[:, 1:]
            want = []
            for k, j in enumerate(js):
                # safeguard: the residual's sign moves the bracket; a Newton step that leaves it bisects
                lo, hi = brackets[j]
                lo = ca.if_else(r[j] < 0, ca.fmax(lo, z[j]), lo)
                hi = ca.if_else(r[j] > 0, ca.fmin(hi, z[j]), hi)
                brackets[j] = [lo, hi]
                zj = z[j] + step[j]
                if j in logs:
                    # a law logarithmic in the speed (rate-and-state): Newton's correction applied to
                    # asinh(v / floor), i.e. multiplicatively where |v| >> floor; in the speed itself it
                    # overshoots from above (the log is concave) and crawls from below (tens of iterations)
                    nu = floors[j]
                    zj = nu * ca.sinh(ca.asinh(z[j] / nu) + step[j] / ca.sqrt(z[j] ** 2 + nu ** 2))
                tol = 1e-9 * ca.fabs(z[j]) + 1e-3 * floors[j]   # a converged step may round past its bracket
                want.append(ca.if_else(ca.logic_and(zj >= lo - tol, zj <= hi + tol), zj,
                                       _split(lo, hi, floors[j])) - z[j])
            # the other states follow the replaced speeds through the same linearisation: the step
            # plus a combination of M^-1 e_j (rows j relax, every other row keeps its Newton equation)
            ws = ca.vertcat(*[w[j, :] for j in js])
            mu = ca.solve(ws, ca.vertcat(*want) - ca.vertcat(*[step[j] for j in js]))
            z = z + step + ca.mtimes(w, mu)
        return z

    if stiff and band is None:
        raise ValueError("sdirk2: the contact speeds' regularisation band is needed with stiff indices")
    z1 = newton_stage(x, x)
    k1 = (z1 - x) / gh
    base2 = x + (1 - GAMMA) * h * k1
    z2 = newton_stage(base2, z1)
    out = [z2]
    if quad is not None:
        out.append(h * ((1 - GAMMA) * quad(z1, u, p) + GAMMA * quad(z2, u, p)))
    if residual:
        r1 = z1 - x - gh * f_at(z1)
        r2 = z2 - base2 - gh * f_at(z2)
        out.append(ca.fmax(ca.norm_inf(r1), ca.norm_inf(r2)))
    if jac:
        out += _ift_jacobians(f, x, u, p, gh, z1, z2, jac)
    return out[0] if len(out) == 1 else tuple(out)


def _ift_jacobians(f, x, u, p, gh, z1, z2, names) -> list:
    """``d z2 / d arg`` for ``arg`` named in ``names`` (``"x"``, ``"u"``, ``"p"``), by the implicit function
    theorem at the stages' values ``z1``, ``z2`` (expressions of the arguments).

    The stages solve ``z1 = x + gh f(z1)`` and ``z2 = b + gh f(z2)`` with ``b = x + c (z1 - x)``,
    ``c = (1 - gamma) / gamma`` (the step's own form of ``x + (1 - gamma) h k1``), so with
    ``M_i = I - gh df/dz (z_i)``::

        M1 dz1 = dx + gh df/darg (z1) darg,    M2 dz2 = (1 - c) dx + c dz1 + gh df/darg (z2) darg

    Built on fresh symbols of the stages and substituted afterwards: no derivative flows through the
    Newton iterations that computed ``z1``, ``z2``."""
    kind = ca.MX if isinstance(x, ca.MX) else ca.SX
    n = x.numel()
    args = {"x": x, "u": u, "p": p}
    a1, a2 = kind.sym("a1", n), kind.sym("a2", n)
    f1, f2 = f(a1, u, p), f(a2, u, p)
    eye = kind.eye(n)
    M1 = eye - gh * ca.jacobian(f1, a1)
    M2 = eye - gh * ca.jacobian(f2, a2)
    c = (1.0 - GAMMA) / GAMMA
    outs = []
    for name in names:
        a = args[name]
        if name == "x":
            d1 = ca.solve(M1, eye)
            d2 = ca.solve(M2, (1.0 - c) * eye + c * d1)
        else:
            d1 = ca.solve(M1, gh * ca.jacobian(f1, a))
            d2 = ca.solve(M2, c * d1 + gh * ca.jacobian(f2, a))
        outs.append(d2)
    return [ca.substitute(d, ca.vertcat(a1, a2), ca.vertcat(z1, z2)) for d in outs]
