"""The identifier's KKT solves (:class:`estimators.identify.shooting.KKTFactor`): accurate to a
backward error of 1e-12 without leaving the banded, diagonal-pivot factorisation when iterative
refinement converges slowly (the lead screw's log of the rig zoo: backward errors of 1e-10 after
four refinement steps sent half of its factorisations to threshold pivoting, 60x slower)."""

from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from estimators.identify.shooting import KKTFactor


def _kkt(nw=80, m=40):
    H = sp.diags(np.logspace(-4, 0, nw))
    A = sp.random(m, nw, density=0.05, random_state=1) + sp.eye(m, nw)
    K = sp.bmat([[H, A.T], [A, -1e-12 * sp.identity(m)]], format="csc")
    return K, SimpleNamespace(kkt_order=lambda n_extra, n=nw + m: np.arange(n))


def test_a_quasi_definite_kkt_is_solved_in_its_banded_order():
    K, prob = _kkt()
    f = KKTFactor(prob, K)
    b = np.random.default_rng(0).standard_normal(K.shape[0])
    x = f.solve(b)
    assert not f.pivoting
    assert f._backward(x, b) <= 1e-12
    assert np.allclose(K @ x, b, rtol=0, atol=1e-9 * np.max(np.abs(b)))


def test_slow_refinement_is_finished_by_gmres_not_by_threshold_pivoting():
    # factors of a perturbed matrix: refinement only halves the error per step (it would need
    # about 30 steps), GMRES preconditioned by the same factors reaches 1e-12
    K, prob = _kkt()
    rng = np.random.default_rng(1)
    f = KKTFactor(prob, K)
    Kp = (K + sp.diags(1.2 * np.abs(K.diagonal()) * rng.uniform(0.5, 1.0, K.shape[0]))).tocsc()
    f.lu = spla.splu(Kp, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    b = rng.standard_normal(K.shape[0])
    x = f.lu.solve(b)
    for _ in range(4):
        x = x + f.lu.solve(b - K @ x)
    assert f._backward(x, b) > 1e-6                 # four refinement steps are far from enough
    xs = f.solve(b)
    assert not f.pivoting                           # no fallback to the fill-heavy factorisation
    assert f._backward(xs, b) <= 1e-12
    # several right-hand sides at once (the covariance's solves)
    B = rng.standard_normal((K.shape[0], 3))
    X = f.solve(B)
    assert X.shape == B.shape and not f.pivoting
    assert all(f._backward(X[:, j], B[:, j]) <= 1e-12 for j in range(3))
