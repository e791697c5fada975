"""Encoder zeros and what a fit owes to them (issue 18, the rig zoo's 1-body finding).

A 1-body lab rig on a speed drive without a torque sensor (tests/data/lab_one_body.toml), 4 s from
rest, k and the kinetic level free, started 20 % off.  With the encoders' zero free the friction
level and the power-on twist trade off; the fit said mu_k 0.265 +- 0.003 against 0.3, status OK.
"""

import dataclasses
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from estimators.identify import IdentifyOptions, identify
from models.status import Status
from test_identify_scales import from_rest

RIG = Path(__file__).parent / "data" / "lab_one_body.toml"


@pytest.fixture(scope="module")
def case():
    m, p, _, sim = from_rest(RIG)
    return m, p, sim.to_log(), p.replace(k0=1.2 * p.k0, mu_k=1.2 * p.mu_k)


def _fit(case, **kw):
    m, p, log, start = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(log, m, start, IdentifyOptions(free=("k0", "mu_k"), **kw))


def test_free_zero_is_not_confidently_wrong(case):
    """The friction level's error covers the truth: it includes the regularisation's bias, which the
    trade with the power-on twist magnifies (-0.012 at this rig's eps, six standard errors)."""
    fit = _fit(case, encoder_zero="free")
    mu, err = fit.estimate[1], fit.error[1]
    assert abs(mu - 0.3) <= 4 * err, (mu, fit.stderr[1], err)
    assert fit.eps_bias is not None and fit.eps_bias[1] < -2 * fit.stderr[1] and err > fit.stderr[1]
    assert fit.offset_error is None                    # a free zero absorbs the encoders' power-on phase
    assert fit.as_dict()["parameters"]["mu_k"]["eps_bias"] == fit.eps_bias[1]


def test_the_trade_off_with_the_power_on_twist_is_named(case):
    """At rig3's eps (0.005 rad/s, three times this rig's default) the kinetic level and the encoder
    zero correlate at -0.97: a warning names the pair and what would separate them; status WARNING."""
    fit = _fit(case, encoder_zero="free", eps=0.005)
    assert fit.zero_corr.shape == (2, 1) and fit.zero_corr[1, 0] < -0.95
    msg = [w for w in fit.warnings if "encoder zero of theta_b0-theta_drive" in w]
    assert msg and msg[0].startswith("mu_k and the encoder zero") and "untwisted" in msg[0], fit.warnings
    assert fit.status is Status.WARNING and abs(fit.estimate[1] - 0.3) <= 4 * fit.error[1]


def test_untwisted_counts_the_encoders_power_on_phase(case):
    """Untwisted at power-on, yet each encoder stood somewhere within a tick: the difference is off by
    a constant of its quantisation level (the simulated log: +1.5e-3 rad, 0.8 of it).  Taken as
    exact, the fit said mu_k 0.291 +- 0.0007 at this rig's eps; its error now includes what such a
    constant does to it."""
    m = case[0]
    fit = _fit(case, encoder_zero="untwisted")
    assert fit.eps == pytest.approx(0.005 / np.pi)
    assert abs(fit.estimate[1] - 0.3) <= 4 * fit.error[1], (fit.estimate, fit.stderr, fit.error)
    assert abs(fit.estimate[0] - m.published().k0) <= 4 * fit.error[0]
    assert fit.offset_error[1] > 5 * fit.stderr[1] and fit.encoder_zero == ({},)
    # the phase's share per encoder (two encoders: one difference) adds up to it; the 95 % interval takes it
    # as the bounded error it is: shorter than 1.96 total errors, longer than the normal parts' 1.96
    assert fit.phase_parts.shape == (2, 2)
    np.testing.assert_allclose(np.sqrt(np.sum(fit.phase_parts ** 2, axis=1)), fit.offset_error)
    assert np.all(fit.interval < 1.959 * fit.error) and np.all(fit.interval > 1.96 * fit.stderr)
    # the regularisation's signed bias moves the interval's centre instead of widening it; a refit's
    # unsigned syserr (systematic = true) widens it and moves nothing
    np.testing.assert_allclose(fit.centre, fit.estimate - fit.eps_bias)
    np.testing.assert_allclose(fit.bounds, np.column_stack([fit.centre - fit.interval, fit.centre + fit.interval]))
    refit = dataclasses.replace(fit, syserr=np.abs(fit.eps_bias))
    np.testing.assert_allclose(refit.centre, fit.estimate)
    assert np.all(refit.interval > fit.interval)
    # within the parameters' admissible range (here made to start at the centre): never below a bound
    at_centre = dataclasses.replace(fit, problem=SimpleNamespace(lo=fit.centre, hi=fit.centre + 10 * fit.interval))
    np.testing.assert_allclose(at_centre.bounds, np.column_stack([fit.centre, fit.centre + fit.interval]))
    lo, hi = fit.as_dict()["parameters"]["mu_k"]["bounds95"]
    assert lo < fit.centre[1] < hi and hi - lo == pytest.approx(2 * fit.interval[1])
    # the deviation it stands for is the difference's own quantisation level
    assert fit.noise["theta_b0-theta_drive"] == pytest.approx(np.hypot(2 * np.pi / 2048, 2 * np.pi / 1024) / np.sqrt(12))


def test_twists_that_share_an_encoder_share_its_power_on_phase():
    """Each encoder's phase at power-on is one constant (variance q^2/12); angle differences taken as
    twists carry the difference of their encoders' constants, so two twists sharing an encoder are
    correlated: ``a - b`` with ``b - c`` by -q_b^2 / (sqrt(q_a^2 + q_b^2) sqrt(q_b^2 + q_c^2)) (equal
    resolutions: -1/2), ``a - b`` with ``a - c`` by +1/2, and not at all without a shared encoder.
    Counted as independent, the zoo's 3-body lab rig stated mu_k at 4.9 % against a spread of 3.5 % over
    50 logs (benchmarks/identify_coverage.py); with the shared phases, 3.7 % against 3.4 %."""
    from types import SimpleNamespace as T
    from estimators.identify.assemble import offset_correlation
    from models import get_model
    from models.sensors import SensorOptions
    from models.sensors import channel_std
    m = get_model("rig3")
    v1, v2, v3 = (channel_std(m, f"theta{i}", 0.01, SensorOptions()) ** 2 for i in (1, 2, 3))
    assert v1 == v2 != v3                            # the discs' encoders alike, the motor's finer
    tw = lambda a, b: T(parts=(a, b))                # noqa: E731
    R = offset_correlation(m, [tw("theta1", "theta2"), tw("theta2", "theta3"), tw("theta1", "theta3")],
                           0.01, SensorOptions())
    expect = [[1.0, -v2 / np.sqrt((v1 + v2) * (v2 + v3)), v1 / np.sqrt((v1 + v2) * (v1 + v3))],
              [0.0, 1.0, v3 / np.sqrt((v2 + v3) * (v1 + v3))], [0.0, 0.0, 1.0]]
    expect = np.triu(expect) + np.triu(expect, 1).T
    assert R == pytest.approx(expect) and R[0, 1] < -0.69          # q_1 = q_2 >> q_3: about -1/sqrt(2)
    assert offset_correlation(m, [tw("theta1", "theta2")], 0.01, SensorOptions()) == pytest.approx(np.eye(1))
    # the same constants as sums of the encoders' unit phases: each row has unit variance
    from estimators.identify.assemble import offset_phases
    M = offset_phases(m, [tw("theta1", "theta2"), tw("theta2", "theta3")], 0.01, SensorOptions())
    assert M.shape == (2, 3) and np.sum(M ** 2, axis=1) == pytest.approx([1.0, 1.0])


def test_the_95_percent_interval_of_a_normal_error_plus_encoder_phases():
    """``interval_halfwidth``: a normal error alone, 1.95996 standard deviations; one uniform phase alone,
    95 % of its half-width; two equal ones (a triangle), ``a (1 - sqrt(0.05))``; a mix against 4 million
    draws (the quantile's own scatter there is about 1e-3)."""
    from estimators.identify.covariance import interval_halfwidth
    assert interval_halfwidth(2.0) == pytest.approx(2.0 * 1.959964, rel=1e-6)
    assert interval_halfwidth(0.0, [1.0]) == pytest.approx(0.95 * np.sqrt(3.0), rel=1e-6)
    a = 0.3                                              # each phase's half-width a / 2: their sum on [-a, a]
    assert interval_halfwidth(0.0, [a / 2 / np.sqrt(3.0)] * 2) == pytest.approx(a * (1 - np.sqrt(0.05)), rel=1e-6)
    rng = np.random.default_rng(7)
    n = 4_000_000
    e = rng.normal(0.0, 0.5, n) + rng.uniform(-2.0, 2.0, n) + rng.uniform(-0.7, 0.7, n)
    h = interval_halfwidth(0.5, [2.0 / np.sqrt(3.0), 0.7 / np.sqrt(3.0)])
    assert h == pytest.approx(np.quantile(np.abs(e), 0.95), rel=2e-3)
    assert h < 1.959964 * np.sqrt(0.25 + 4.0 / 3.0 + 0.49 / 3.0)          # shorter than the normal reading
