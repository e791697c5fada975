"""The one-call factory of the NMPC's OCP solvers: a name ("rti", "sqp", "ipopt") to a solver
(:class:`mitigate.controllers.nmpc.ocp.OCPSolver` subclasses)."""

from __future__ import annotations

from models.errors import ConfigError
from mitigate.controllers.nmpc.ipopt import IpoptSolver
from mitigate.controllers.nmpc.layout import OCPSpec
from mitigate.controllers.nmpc.ocp import OCPSolver
from mitigate.controllers.nmpc.options import SOLVERS
from mitigate.controllers.nmpc.rti import GaussNewtonSolver

__all__ = ["make_ocp_solver"]


def make_ocp_solver(model, spec: OCPSpec, *, solver: str = "rti", compile: bool = True, qp_solver: str = "hpipm",
                    qp_tol: float = 1e-7, sqp_max_iter: int = 20, sqp_tol: float = 1e-6, qp_mode: str = "speed_abs",
                    qp_mu0: float | None = None) -> OCPSolver:
    """The OCP solver a name asks for.

    Parameters
    ----------
    model, spec : the rig and the OCPSpec
    solver : "rti" | "sqp" (:class:`mitigate.controllers.nmpc.rti.GaussNewtonSolver`) or "ipopt"
        (:class:`mitigate.controllers.nmpc.ipopt.IpoptSolver`)
    compile : compile the stage functions (gcc, cached) for "rti"/"sqp"
    qp_solver : "hpipm" (direct), "qrqp" or "osqp" (CasADi ``conic``)
    qp_tol : QP tolerance; "sqp" uses min(qp_tol, sqp_tol / 10) so that its step test can pass
    sqp_max_iter, sqp_tol : Gauss-Newton iterations and step tolerance of "sqp"
    qp_mode, qp_mu0 : hpipm's preset and initial complementarity (None: the preset's)

    Raises
    ------
    ConfigError : an unknown solver.
    """
    if solver == "ipopt":
        return IpoptSolver(model, spec)
    if solver in ("rti", "sqp"):
        return GaussNewtonSolver(model, spec, iterate=solver == "sqp", compile=compile, qp_solver=qp_solver,
                                 qp_tol=qp_tol, sqp_max_iter=sqp_max_iter, sqp_tol=sqp_tol,
                                 qp_mode=qp_mode, qp_mu0=qp_mu0)
    raise ConfigError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
