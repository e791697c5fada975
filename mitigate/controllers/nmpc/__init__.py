"""Nonlinear MPC on any rig: options (:mod:`.options`), the OCP's structure (:mod:`.layout`) and
stage functions built from a rig model (:mod:`.stage`), the warm-started OCP and its solvers
(:mod:`.ocp`; Gauss-Newton RTI/SQP :mod:`.rti`, IPOPT :mod:`.ipopt`), the stage-wise QP and the
QP solvers (:mod:`.qp`), and the controller (:mod:`.controller`).

Example
-------
>>> from mitigate.controllers.nmpc import NMPC, NMPCOptions
>>> nmpc = NMPC(NMPCOptions(horizon=50, inputs="pin"), context)      # context: ControlContext
>>> action = nmpc.step(t, measurement, estimate)                     # action.u == {"n2": ...}
"""

from mitigate.controllers.nmpc.controller import NMPC, resolve_inputs
from mitigate.controllers.nmpc.layout import OCPLayout, OCPSpec
from mitigate.controllers.nmpc.ocp import OCPResult, OCPSolver
from mitigate.controllers.nmpc.solvers import make_ocp_solver
from mitigate.controllers.nmpc.stage import stage_functions
from mitigate.controllers.nmpc.options import MAX_HORIZON, NMPCOptions, NMPCWeights

__all__ = ["NMPC", "NMPCOptions", "NMPCWeights", "MAX_HORIZON", "resolve_inputs", "OCPSpec",
           "OCPLayout", "OCPSolver", "OCPResult", "make_ocp_solver", "stage_functions"]
