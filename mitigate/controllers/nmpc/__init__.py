"""Nonlinear MPC on any rig: options (:mod:`.options`), the OCP built from a rig model
(:mod:`.ocp`), its stage-wise QP and the QP solvers (:mod:`.qp`), and the controller
(:mod:`.controller`).

Example
-------
>>> from mitigate.controllers.nmpc import NMPC, NMPCOptions
>>> nmpc = NMPC(NMPCOptions(horizon=50, inputs="pin"), context)      # context: ControlContext
>>> action = nmpc.step(t, measurement, estimate)                     # action.u == {"n2": ...}
"""

from mitigate.controllers.nmpc.controller import NMPC, resolve_inputs
from mitigate.controllers.nmpc.ocp import OCPLayout, OCPResult, OCPSolver, OCPSpec, stage_functions
from mitigate.controllers.nmpc.options import MAX_HORIZON, NMPCOptions, NMPCWeights

__all__ = ["NMPC", "NMPCOptions", "NMPCWeights", "MAX_HORIZON", "resolve_inputs", "OCPSpec",
           "OCPLayout", "OCPSolver", "OCPResult", "stage_functions"]
