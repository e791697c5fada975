"""The operating point and the small builders the NMPC test files share (tests/test_nmpc.py,
tests/test_nmpc_closed_loop.py): rig3 at 30 rpm and N1 = 20 N, a control context, an NMPC without
compilation, an estimate holding the true state, and an action applied to the programme.
"""

from __future__ import annotations

import numpy as np

from estimators.base import Estimate
from mitigate.controllers.base import ControlContext
from mitigate.controllers.factory import make_controller
from mitigate.controllers.nmpc import NMPC
from models import get_model

M = get_model("rig3")
P = M.published()
W0 = np.pi          # 30 rpm [rad/s]
U0 = np.array([W0, 20.0, 0.0])


def context(model=M, params=None, programme=None, dt=0.01, where="nmpc"):
    model = get_model(model)
    u = U0 if programme is None else programme
    prog = u if callable(u) else (lambda t, u=np.asarray(u, float): u)
    return ControlContext(model, model.published() if params is None else params, dt, prog, where=where)


def nmpc(opts=None, **kw) -> NMPC:
    return make_controller({"kind": "nmpc", "compile": False, **(opts or {})}, context(**kw))


def estimate(t, x, model=M):
    return Estimate(t, np.asarray(x, float).copy(), None, model.states)


def apply_action(model, u_prog, action):
    u = np.array(u_prog, float)
    for name, v in action.u.items():
        u[model.inputs.index(name)] = v
    return u
