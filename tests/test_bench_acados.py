"""``benchmarks/bench_acados.py`` hands the NMPC's OCP to acados' older casadi as SX instruction
lists (``benchmarks/_acados_side.py``: ``dump_sx`` / ``load_sx``).  The transfer must rebuild
every operation exactly: here within one casadi version (acados' own venv runs the same check
against the workbench's evaluations at every run)."""

import importlib.util
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

SIDE = Path(__file__).resolve().parent.parent / "benchmarks" / "_acados_side.py"


@pytest.fixture(scope="module")
def side():
    spec = importlib.util.spec_from_file_location("_acados_side", SIDE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _roundtrip(side, f):
    data = side.dump_sx(f, "f")
    for k, v in data.items():        # what np.savez / np.load(allow_pickle=False) can carry
        assert v.dtype != object, k
    return side.load_sx(data, "f")


def test_every_kind_of_operation_is_rebuilt_exactly(side):
    x, y = ca.SX.sym("x", 3), ca.SX.sym("y", 2)
    e = ca.vertcat(ca.sin(x[0]) * y[0] + 3.25, ca.atan2(x[1], y[1]), ca.tanh(x[2] / 0.05),
                   ca.if_else(x[0] > y[0], x[1] ** 2, ca.sqrt(ca.fabs(y[1]))), ca.fmin(x[0], -x[2]),
                   ca.exp(-x[1]) - ca.log1p(ca.fabs(x[2])), 1e-300 * x[0], ca.constpow(x[1], 3))
    f = ca.Function("f", [x, y], [e, ca.sumsqr(x)], ["x", "y"], ["e", "s"])
    g = _roundtrip(side, f)
    assert g.name_in() == ["x", "y"] and g.name_out() == ["e", "s"]
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = rng.standard_normal(3), rng.standard_normal(2)
        for want, got in zip(f(a, b), g(a, b)):
            assert np.array_equal(np.array(want), np.array(got))


def test_sparse_outputs_and_inputs_keep_their_pattern(side):
    x = ca.SX.sym("x", ca.Sparsity.lower(3))
    out = ca.SX(ca.Sparsity.diag(3), ca.vertcat(x[0, 0], 2 * x[1, 1], x[2, 2] * x[2, 0]))
    f = ca.Function("f", [x], [out])
    g = _roundtrip(side, f)
    assert g.sparsity_in(0) == f.sparsity_in(0) and g.sparsity_out(0) == f.sparsity_out(0)
    v = ca.DM(ca.Sparsity.lower(3), np.arange(1.0, 7.0))
    assert np.array_equal(np.array(f(v)), np.array(g(v)))


def test_a_function_that_calls_another_is_refused(side):
    x = ca.SX.sym("x")
    inner = ca.Function("inner", [x], [ca.sin(x)], {"never_inline": True})
    outer = ca.Function("outer", [x], [inner(x) + 1])
    if all(outer.instruction_id(k) != ca.OP_CALL for k in range(outer.n_instructions())):
        pytest.skip("this casadi inlined the call")
    with pytest.raises(ValueError, match="inline"):
        side.dump_sx(outer, "f")
