"""What a fit's structure misses (estimators.identify.diagnostics) and how a fit ends
(estimators.identify.result.fit_status): known residuals, no fits."""

import numpy as np
import pytest

from estimators.identify.diagnostics import (LAG1_CORRELATED, SHARE_DOMINANT, SLOW_ABOVE_NOISE, diagnose, gap_locator, lag1,
                                             ljung_box, residual_peak)
from estimators.identify.result import BEST_FIT, fit_status
from models.status import Status

DT = 0.01
T = np.arange(3000) * DT


def _signal():
    return np.maximum(0.0, np.sin(2 * np.pi * 0.8 * T)) * 5.0      # a stick-slip-like speed at 0.8 Hz


def test_white_noise_is_white():
    r = np.random.default_rng(0).normal(size=T.size)
    assert abs(lag1(r)) < 3 / np.sqrt(r.size)
    assert ljung_box(r)[1] > 0.01
    f0, share = residual_peak([r], DT)
    assert share < SHARE_DOMINANT
    d = diagnose([{"omega": r}], [{"omega": _signal()}], DT, sigma2=1.0)
    assert d.structure_ok and d.white and d.slow_rms["omega"] < 0.3 and d.rms["omega"] == pytest.approx(1, abs=0.05)


def test_an_unmodelled_oscillation_is_a_miss_and_says_where():
    rng = np.random.default_rng(1)
    r = 3.0 * np.sin(2 * np.pi * 1.6 * T) + rng.normal(size=T.size)        # twice the signal's frequency
    d = diagnose([{"omega": r[:1500], "twist": rng.normal(size=1500)},
                  {"omega": r[1500:], "twist": rng.normal(size=1500)}],
                 [{"omega": _signal()[:1500], "twist": T[:1500]}, {"omega": _signal()[1500:], "twist": T[1500:]}],
                 DT, sigma2=5.5)
    assert d.channel == "omega" and not d.structure_ok and not d.white and d.dominant
    assert d.peak_frequency == pytest.approx(1.6, abs=0.1) and d.peak_share > 0.5
    assert d.slow_rms["omega"] > SLOW_ABOVE_NOISE and d.lag1 > LAG1_CORRELATED
    assert "Hz (2 x the measured signal's dominant frequency 0.8 Hz) with" in d.summary()
    assert d.summary().startswith("structure misses: the omega residual below 4 Hz is 2.1 times")


@pytest.mark.parametrize("level, miss", [(0.06, False), (0.3, False), (0.8, True)])
def test_a_correlated_residual_far_below_the_noise_is_not_a_miss(level, miss):
    """A residual at the cycle's frequency whose RMS is a small fraction of the sensors' noise (the
    regularised friction's creep on a log of the model's own plant: 0.057 noise levels) is below
    what the sensors resolve; at 0.8 noise levels it is a miss."""
    r = np.sin(2 * np.pi * 0.8 * T) + 0.05 * np.random.default_rng(2).normal(size=T.size)
    r = level * r / np.sqrt(np.mean(r ** 2))
    d = diagnose([{"torque": r}], [{"torque": _signal()}], DT, sigma2=level ** 2)
    assert d.lag1 > LAG1_CORRELATED and d.dominant
    assert d.slow_rms["torque"] < SLOW_ABOVE_NOISE
    assert d.structure_ok is (not miss)


def test_blue_quantisation_noise_is_not_a_miss():
    """Speeds from differences of quantised angles: negatively correlated, mostly fast."""
    q = np.floor(np.cumsum(np.full(T.size, 0.37)))                # a counted angle
    r = np.diff(np.r_[0.0, q]) - 0.37
    r = r / r.std()
    d = diagnose([{"omega": r}], [{"omega": _signal()}], DT, sigma2=1.0)
    assert d.lag1 < 0 and d.structure_ok


def test_gaps_left_at_nodes_are_a_miss_located_by_log_time_and_state():
    where = gap_locator([3, 2], [np.arange(31) * DT, 5 + np.arange(21) * DT], 10, ("twist", "omega"))
    gaps = np.zeros(10)
    gaps[7] = 3e-3                          # interval 3 (the first of log 2), state 1
    assert where(7) == (2, pytest.approx(5.1), "omega")
    assert where(0) == (1, pytest.approx(0.1), "twist")
    r = np.random.default_rng(2).normal(size=T.size)
    d = diagnose([{"omega": r}], [{"omega": _signal()}], DT, sigma2=1.0, gaps=gaps, gap_locator=where)
    assert d.max_gap == pytest.approx(3e-3) and (d.gap_log, d.gap_state) == (2, "omega")
    assert d.misses == ("continuity gaps remain at the shooting nodes (largest 0.003, scaled at log 2, t = 5.1 s, "
                        "state omega)",)


class _Misses:
    misses = ("the omega residual below 4 Hz is 3 times the sensors' noise",)
    max_gap = 0.0


class _Ok:
    misses = ()
    max_gap = 0.0


class _Gaps:
    misses = ("the omega residual below 4 Hz is 3 times the sensors' noise",
              "continuity gaps remain at the shooting nodes (largest 0.45, scaled)")
    max_gap = 0.45


@pytest.mark.parametrize("reason, success, structure, hist, want, prefix", [
    ("small_step", True, _Ok(), (), Status.OK, "converged"),
    ("small_step", True, _Misses(), (), Status.WARNING, f"{BEST_FIT} (converged); structure misses: the omega"),
    # a failed line search that would still lower the cost by 0.05 %: the model's best, stationary
    ("line_search", False, _Misses(), (("predicted_decrease", 50.0),), Status.WARNING,
     f"{BEST_FIT} (the solver stopped: line search failed; the cost would fall by less than 0.1 % more)"),
    # ... by 5 %: not converged, with advice, whatever the structure
    ("line_search", False, _Misses(), (("predicted_decrease", 5000.0),), Status.NOT_CONVERGED, "line search failed"),
    # stationary, but with gaps open: its parameters belong to no trajectory (issue 28: reported "ok, with warnings")
    ("line_search", False, _Gaps(), (("predicted_decrease", 50.0),), Status.NOT_CONVERGED, "line search failed"),
    # at the iteration limit: never OK nor WARNING, however flat the cost
    ("max_iter", False, _Misses(), (), Status.NOT_CONVERGED, "line search failed"),
    ("max_iter", False, _Gaps(), (), Status.NOT_CONVERGED, "line search failed"),
    ("line_search", False, _Ok(), (("predicted_decrease", 50.0),), Status.NOT_CONVERGED, "line search failed"),
    # a rough cost (issue 28's 168 N/m slider): the model promises 5 % more, no step gives it, and that step
    # would move no parameter by more than 0.02 of its standard error: stationary at its error bars' resolution
    ("line_search", False, _Misses(), (("predicted_decrease", 5000.0), ("step_in_stderr", 0.021)), Status.WARNING,
     f"{BEST_FIT} (the solver stopped: line search failed; the step left would move no parameter by more than "
     f"0.021 of its standard error)"),
    # ... by half a standard error: not converged
    ("line_search", False, _Misses(), (("predicted_decrease", 5000.0), ("step_in_stderr", 0.5)),
     Status.NOT_CONVERGED, "line search failed"),
    # ... nor with gaps open, nor at the iteration limit
    ("line_search", False, _Gaps(), (("predicted_decrease", 5000.0), ("step_in_stderr", 0.021)),
     Status.NOT_CONVERGED, "line search failed"),
    ("max_iter", False, _Misses(), (("step_in_stderr", 0.021),), Status.NOT_CONVERGED, "line search failed"),
])
def test_fit_status(reason, success, structure, hist, want, prefix):
    msg = "converged" if success else "line search failed. Try: more"
    status, text = fit_status(reason, success, msg, warned=False, structure=structure, history=hist, cost=1e5)
    assert status is want and text.startswith(prefix)
    if want is Status.NOT_CONVERGED:
        assert text == msg


REFINED = "the line search failed; continuity gaps remain (largest 0.4, scaled); largest continuity gap 0.4 (scaled)"


@pytest.mark.parametrize("reason, success, structure, warned, want, prefix", [
    # the single-shooting refinement converged on a model that misses: the best fit within it
    ("small_step", True, _Misses(), False, Status.WARNING,
     f"{BEST_FIT} (the multiple-shooting fit ended: {REFINED}; continued by single shooting (simulation error): "
     f"converged); structure misses: the omega"),
    # ... on a model that follows the log (the gaps were the solver's trouble): converged
    ("small_step", True, _Ok(), False, Status.OK, "converged (the multiple-shooting fit ended: "),
    ("small_step", True, _Ok(), True, Status.WARNING, "converged (the multiple-shooting fit ended: "),
    # the refinement at its own iteration limit: not converged
    ("max_iter", False, _Misses(), False, Status.NOT_CONVERGED, "stopped. Try: more (the multiple-shooting fit ended"),
])
def test_fit_status_after_a_single_shooting_refinement(reason, success, structure, warned, want, prefix):
    msg = "converged" if success else "stopped. Try: more"
    status, text = fit_status(reason, success, msg, warned=warned, structure=structure, cost=1e5, refined=REFINED)
    assert status is want and text.startswith(prefix), text


def test_identifiability_warnings_alone_give_warning_without_best_fit():
    status, text = fit_status("small_step", True, "converged", warned=True, structure=_Ok())
    assert status is Status.WARNING and text == "converged"
