"""A fit always ends usable and honest (issue 28).

- gaps that will not close: the fit continues by single shooting (simulation error) from the best
  multiple-shooting estimate, so its parameters belong to one trajectory of the model
  (estimators/identify/single.py); its Jacobian is the multiple-shooting one condensed, checked here
  against finite differences;
- a fit at its iteration limit is never OK nor WARNING, and is not refined (the budget is the user's);
- of a direct fit and a continuation the lower consistent cost is kept (one fit had kept 2.989e4 over
  2.369e4);
- the start-up estimator's failure is in the result, not dropped;
- a steady-sliding hold-out states no stick-slip period and no NRMSE of noise;
- no ``--encoder-zero untwisted`` advice where a torque is compared; a fitted set names its rig file
  relative to itself.
"""

import dataclasses
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from estimators.identify import IdentificationProblem, IdentifyOptions, identify
from estimators.identify.continuation import CORNER_SIGMA2, choose, wants_continuation
from estimators.identify.covariance import Uncertainty
from estimators.identify.gauss_newton import GAP_OK
from estimators.identify.result import BEST_FIT, identifiability_warnings
from estimators.identify.single import SS_METHOD, SimulationError, refine
from models import get_model, load_params
from models.errors import ConfigError
from models.plant import SimOptions, simulate
from models.status import Status

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

DISC_FREE = ("k", "d", "mu_k", "mu_s")


@pytest.fixture(scope="module")
def disc():
    """A 6 s stick-slip log of the disc's exact plant and a converged fit of it (from 20 % off)."""
    m = get_model("disc")
    true = m.published()
    log = simulate(m, true, np.array([1.0, 20.0]), 6.0, SimOptions(seed=2)).to_log()
    start = true.replace(**{n: 1.2 * true[n] for n in DISC_FREE})
    prob = IdentificationProblem(m, log, start, IdentifyOptions(free=DISC_FREE, encoder_zero="untwisted",
                                                                 globalise="off"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = prob.solve()
    assert fit.success, fit.message
    return m, true, log, prob, fit


def test_simulation_error_jacobian_is_the_condensed_multiple_shooting_one(disc):
    m, true, log, prob, fit = disc
    sh = prob.shooting()
    ss = SimulationError(sh, prob.values_function, [d.nint for d in prob.data])
    v = ss.start(prob.decision_vector(None))
    r, g, J, A, _ = ss.evaluate(v)
    assert g.size == 0 and A.shape == (0, ss.nw) and J.shape == (r.size, ss.nw)
    # the nodes are one simulation: the multiple-shooting gaps on them vanish
    w = ss.full(v)
    assert np.max(np.abs(sh.evaluate(w, jac=False)[1])) < 1e-9
    J = J.toarray()
    for j in range(ss.nw):
        h = 1e-6 * max(1.0, abs(v[j]))
        vp, vm = v.copy(), v.copy()
        vp[j] += h
        vm[j] -= h
        fd = (ss.evaluate(vp, jac=False)[0] - ss.evaluate(vm, jac=False)[0]) / (2 * h)
        assert np.max(np.abs(fd - J[:, j])) <= 1e-4 * max(1.0, np.max(np.abs(fd))), j


def test_gaps_left_open_continue_by_single_shooting_to_one_trajectory(disc):
    """The converged fit with its nodes knocked off their trajectory (gaps of 0.3 of the states'
    ranges): the refinement starts from its parameters and first node and ends on one simulation,
    where the converged fit was."""
    m, true, log, prob, fit = disc
    rng = np.random.default_rng(0)
    knocked = tuple(s + 0.3 * rng.standard_normal(s.shape) * prob.shooting().x_scale for s in fit.states)
    broken = dataclasses.replace(fit, states=knocked, estimate=fit.estimate * 1.05,
                                 structure=dataclasses.replace(fit.structure, max_gap=0.3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = refine(prob, broken, "the line search failed; continuity gaps remain (largest 0.3, scaled)")
    assert out.structure.max_gap < 1e-9 and out.success
    assert out.message.endswith("continued by single shooting (simulation error))") or BEST_FIT in out.message
    assert "multiple-shooting fit ended: the line search failed" in out.message
    assert out.method.endswith(f"then {SS_METHOD} (its gaps did not close: largest 0.3, scaled)")
    assert out.attempts[-1].method == SS_METHOD and len(out.attempts) == len(fit.attempts) + 1
    assert out.iterations > fit.iterations
    assert np.all(np.abs(out.estimate - fit.estimate) <= 0.25 * fit.stderr), (out.estimate, fit.estimate, fit.stderr)
    assert out.cost == pytest.approx(fit.cost, rel=5e-3)


def test_a_fit_at_its_iteration_limit_is_not_converged_and_not_refined(disc):
    m, true, log, prob, fit = disc
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cut = prob.derive(max_iter=2, globalise="auto").solve()
    assert cut.reason == "max_iter" and cut.status is Status.NOT_CONVERGED and not cut.success
    assert len(cut.attempts) == 1 and cut.message.startswith("stopped at the iteration limit (2 iterations")


@dataclasses.dataclass(frozen=True)
class _Fit:
    """What :func:`choose` reads of a fit."""

    cost: float
    gap: float
    reason: str = "small_step"
    method: str = "GN"
    iterations: int = 10
    wall_time: float = 1.0
    guess_notes: tuple = ()
    attempts: tuple = ()

    @property
    def success(self):
        return self.reason in ("small_step", "no_predicted_decrease", "no_further_decrease")

    @property
    def structure(self):
        return dataclasses.make_dataclass("S", [("max_gap", float)])(self.gap)


def test_the_lower_consistent_cost_is_kept():
    # the reviewer's case: a converged continuation at 2.989e4 was kept over a direct fit at 2.369e4
    assert choose(_Fit(2.369e4, 0.0, "line_search"), _Fit(2.989e4, 0.0), "why").cost == 2.369e4
    # a direct fit with gaps open has no consistent cost: refined first, then compared
    refined = []

    def ss(cost):
        def consistent(f):
            refined.append(f.cost)
            return dataclasses.replace(f, cost=cost, gap=0.0, method=f.method + "; SS", iterations=f.iterations + 5)
        return consistent

    kept = choose(_Fit(2.0e4, 0.45, "line_search"), _Fit(2.989e4, 0.0), "why", ss(2.5e4))
    assert kept.cost == 2.5e4 and kept.method.startswith("GN; SS (why; kept the direct fit: ")
    assert "refined by single shooting to 2.5e+04" in kept.method and kept.iterations == 25
    kept = choose(_Fit(2.0e4, 0.45, "line_search"), _Fit(2.989e4, 0.0), "why", ss(3.2e4))
    assert kept.cost == 2.989e4 and "kept the continuation" in kept.method
    # the same cost, one converged: the converged one (a continuation that stalled 0.004 below a
    # converged direct fit had made the fit "not converged")
    kept = choose(_Fit(3321.3893, 0.0), _Fit(3321.3857, 0.0, "stalled"), "why")
    assert kept.reason == "small_step" and "kept the direct fit" in kept.method
    # one whose gapped cost already exceeds a consistent one is not refined
    refined.clear()
    kept = choose(_Fit(3.5e4, 0.45, "line_search"), _Fit(2.989e4, 0.0), "why", ss(1.0))
    assert kept.cost == 2.989e4 and refined == []


def test_a_converged_fit_against_a_bound_is_repeated_only_if_it_misses_by_more_than_the_noise():
    """The lab string's degenerate corner (v_s = 0, mu_s = mu_k: residual variance 4.6e4 noise
    variances) is repeated along the continuation; the field zoo rig's mu_k = c0 = 0 at 0.31 noise
    variances (from the true set as well) is not: there the bound is where the log leaves a parameter."""
    from types import SimpleNamespace

    def fit(sigma2, at_bound=("v_s",), misses=("the residual is not white",)):
        return SimpleNamespace(reason="no_further_decrease", attempts=(), at_bound=at_bound, active_constraints=(),
                               structure=SimpleNamespace(misses=misses), sigma2=sigma2)

    assert "ended against v_s" in wants_continuation(fit(4.6e4), "auto", False)
    assert wants_continuation(fit(math.nan), "auto", False) is not None         # not known: repeated
    assert wants_continuation(fit(0.31), "auto", False) is None
    assert wants_continuation(fit(0.999 * CORNER_SIGMA2), "auto", False) is None
    assert wants_continuation(fit(4.6e4, at_bound=()), "auto", False) is None      # inside its bounds
    assert wants_continuation(fit(4.6e4, misses=()), "auto", False) is None        # the structure follows
    assert wants_continuation(fit(0.31), "always", False) == "always"
    assert wants_continuation(fit(4.6e4), "auto", True) is None                   # a warm start


@pytest.mark.slow
def test_the_field_rigs_undetermined_kinetic_level_is_not_chased():
    """Zoo field_torque_drive (316 kg m^2, a torque drive at 1 rad/s, 60 s): the direct fit converges in 7
    iterations with mu_k and c0 at 0, at the sensors' noise; the continuation used to run 26 more and end
    at twice the cost.  Now one solve, and its error bars say that mu_k is not determined."""
    from _zoo_rigs import cases

    c = next(c for c in cases(user=False) if c.name == "field_torque_drive")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(c.log(seed=3, duration=60.0), c.model, c.start,
                       IdentifyOptions(free=c.free, encoder_zero="untwisted"))
    assert fit.success and len(fit.attempts) == 1 and fit.iterations <= 10
    assert fit.sigma2 < CORNER_SIGMA2 and "mu_k" in fit.at_bound
    i = fit.names.index("mu_k")
    assert fit.error[i] > 3 * c.truth["mu_k"]             # undetermined, and said so
    for n in ("k0", "k1", "mu_s"):
        j = fit.names.index(n)
        assert abs(fit.estimate[j] - c.truth[n]) <= fit.interval[j], n


def test_the_start_up_estimators_failure_is_reported(monkeypatch):
    """The student rig (its middle disc unmeasured: those states start from the EKF): the EKF
    refusing the log is one warning of the fit, not dropped."""
    import estimators.online.replay as replay

    def refuse(*a, **k):
        raise ConfigError("estimator: rig pin_rig needs 42267 RK4 substeps per 0.01 s step; more than 2000")

    monkeypatch.setattr(replay, "estimate_log", refuse)
    m = get_model(str(Path(__file__).parent / "data" / "userrig" / "pin_rig.toml"))
    p = m.published()
    log = simulate(m, p, np.array([50 * 2 * math.pi / 60, 12.0]), 3.0, SimOptions(seed=1)).to_log()
    prob = IdentificationProblem(m, log, p.replace(k2=0.24), IdentifyOptions(free=("k2",), max_iter=3))
    prob.shooting()
    assert prob.start_notes and prob.start_notes[0].startswith(
        "start-up estimator: the EKF could not run (estimator: rig pin_rig needs 42267 RK4 substeps")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = prob.solve()
    assert any(w.startswith("start-up estimator: the EKF could not run") for w in fit.warnings)
    assert fit.status is not Status.OK


def test_a_steady_sliding_hold_out_states_no_period():
    """The disc at 1 rad/s (stick-slip), then 5 rad/s: the held-out end slides steadily."""
    from mitigate.commands.identify import holdout_line

    m = get_model("disc")
    true = m.published()
    log = simulate(m, true, lambda t: np.array([1.0 if t < 9.0 else 5.0, 20.0]), 16.0, SimOptions(seed=3)).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(log, m, true, IdentifyOptions(free=("k", "mu_k"), encoder_zero="untwisted"), holdout=0.25)
    v = fit.validation
    assert not v.stick_slip and math.isnan(v.period_measured) and math.isnan(v.period_error)
    assert "steady sliding" in v.period_note and v.slips_measured == 0
    assert math.isnan(v.amplitude_measured)
    assert all(math.isfinite(x) for x in v.rms.values())
    line = holdout_line(v, {"omega1": "rad/s"})
    assert " s measured" not in line and "no stick-slip period: the held-out omega1 shows none" in line, line
    # ... the stick-slip part, held out: a period, predicted within 5 %
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(log.slice(0.0, 8.9), m, true, IdentifyOptions(free=("k", "mu_k"), encoder_zero="untwisted"),
                       holdout=0.4)
    v = fit.validation
    assert v.stick_slip and v.kind == "speed" and v.slips_measured >= 3
    assert abs(v.period_error) < 0.05, v
    assert " s measured (" in holdout_line(v, {"omega1": "rad/s"})


def _unc(zero_corr):
    nf = zero_corr.shape[0]
    return Uncertainty(np.eye(nf), np.ones(nf), np.eye(nf), np.ones(1), 1.0, 1.0, 100, 1.0, (), zero_corr)


def test_no_untwisted_advice_where_a_torque_is_compared():
    o = IdentifyOptions(free=("k2", "mu_k"))
    unc = _unc(np.array([[0.1], [0.99]]))
    args = (("k2", "mu_k"), np.array([1.0, 0.3]), np.array([0.01, 0.001]), np.eye(2), unc, (), (), o,
            ["theta_low-theta_mot"])
    without = identifiability_warnings(*args)
    assert any("--encoder-zero untwisted" in w and "a torque sensor" in w for w in without)
    with_torque = identifiability_warnings(*args, torque=True)
    assert [w for w in with_torque if "encoder zero" in w]
    assert not any("untwisted" in w or "a torque sensor" in w for w in with_torque)


def test_a_fitted_set_names_its_rig_file_relative_to_itself(tmp_path):
    rig = Path(__file__).parent / "data" / "lab_string_1dof.toml"
    m = get_model(str(rig))
    out = tmp_path / "results" / "fitted.toml"
    out.parent.mkdir()
    m.published().replace(k=4.0).save(out)
    line = out.read_text().splitlines()[0]
    assert line.startswith('model = "') and not Path(line.split('"')[1]).is_absolute()
    assert line.endswith('lab_string_1dof.toml"')
    assert load_params(out, m)["k"] == 4.0
    get_model("disc").published().save(tmp_path / "disc.toml")            # a shipped rig: its name
    assert (tmp_path / "disc.toml").read_text().splitlines()[0] == 'model = "disc"'


@pytest.mark.slow
def test_a_dc_motor_rig_whose_gaps_stay_open_ends_on_one_trajectory():
    """The zoo's lab rig on a current-limited DC motor (L/R 0.05 ms), 60 s from rest, 5 parameters
    20 % off, the direct fit alone: it ends on ONE trajectory, the truth within the stated errors.
    (Measured before the start-up took the twist from the spring's torque sensor: every gap left open
    sat where the voltage limit engages, a kink no Gauss-Newton step crosses, and the single-shooting
    refinement closed them; now the direct fit closes them itself.  Either way the reported fit is
    consistent; ``test_gaps_left_open_continue_by_single_shooting_to_one_trajectory`` keeps the
    refinement's path under test.)"""
    from _zoo_rigs import cases

    c = {c.name: c for c in cases(0, user=False)}["lab_dc_motor_LR_0.05ms"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(c.log(), c.model, c.start, IdentifyOptions(free=c.free, encoder_zero="untwisted",
                                                                  globalise="off"))
    assert fit.attempts[0].max_gap <= GAP_OK or fit.attempts[-1].method.startswith("single shooting (simulation error)"), fit.attempts
    assert fit.structure.max_gap < 1e-6 and fit.success, fit.message
    for n, v, e in zip(fit.names, fit.estimate, fit.error):
        assert abs(v - c.truth[n]) <= 3 * e, (n, v, e, c.truth[n])


@pytest.mark.slow
def test_a_diverging_direct_fit_hands_over_to_the_continuation_early():
    """rig2's seed-001 setting on a 60 s log, k, c, Tc, Ts free (``bench_identify.py accuracy``): at the
    rig's eps (0.0016 rad/s) the direct fit's cost rose from 1.8e4 to 1.1e6 with its gaps open for all
    its 100 iterations (121 iterations in all, 16.9 s compiled).  It now stops after 8 diverging
    iterations past the first and the continuation in eps converges: one trajectory, the levels within
    2 %, k within 1 %, and far fewer iterations."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from rig2_pi import rig2_pi_log
    from models import published

    true = published("rig2").replace(Ts=0.30, v_s=1.0)
    log = rig2_pi_log(true, 2, 60.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(log, "rig2", published("rig2").replace(Ts=0.27),
                       IdentifyOptions(free=("k", "c", "Tc", "Ts"), encoder_zero="untwisted", compile=False))
    assert fit.attempts[0].reason == "diverging" and fit.attempts[0].iterations <= 12
    assert "diverging" in fit.method and "kept the continuation" in fit.method
    assert fit.success and fit.status is not Status.FAILED and fit.structure.max_gap < GAP_OK
    assert fit.iterations <= 40
    est = dict(zip(fit.names, fit.estimate))
    assert abs(est["k"] / true.k - 1) < 0.01
    assert abs(est["Tc"] / true.Tc - 1) < 0.03 and abs(est["Ts"] / true.Ts - 1) < 0.02


@pytest.mark.slow
def test_a_log_from_rest_starts_the_unmeasured_states_from_rest():
    """Zoo example_1 (``benchmarks/zoo/example_1.toml``: a DC-motor drive that sits at its current limit for
    the log's first 0.57 s, one encoder on the bit, 60 s from rest, 20 % off): its shooting nodes put the
    motor at its set-point and 3.1 A at t = 0, and the fit took 69 iterations (direct fit stalled with gaps
    open, then the continuation) to a cost of 0.37 with mu_cb 10 % off.  Started from rest, where the log
    shows the rig: one direct fit, the lower minimum, every parameter within 3 %."""
    from _zoo_rigs import cases

    c = next(c for c in cases(user=False) if c.name == "example_1")
    truth, start = c.truth, c.start
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(c.log(seed=3, duration=60.0), c.model, start,
                       IdentifyOptions(free=c.free, encoder_zero="untwisted"))
    assert fit.success and len(fit.attempts) == 1 and fit.iterations <= 15
    assert fit.attempts[0].cost < 0.1          # 0.0397 (the sliding start: 0.37)
    for n, v in zip(fit.names, fit.estimate):
        assert abs(v / truth[n] - 1) < 0.03, n
