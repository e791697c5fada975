"""Parametric bootstrap of a fit (estimators.identify.bootstrap).

Independent check: on a log of the EXACT stick/slip plant with known truth, the Gauss-Newton
standard errors miss the truth by many of themselves (quantised encoders, noisy logged force,
regularised model), while the bootstrap's bias, measured on replicates simulated from the FIT,
reproduces the actual error of the fit and its RMS error covers it.  ``bootstrap(fit)`` needs
nothing but the fit: the result carries its problem.
"""

import warnings

import numpy as np
import pytest

from estimators.identify import BootstrapOptions, IdentifyOptions, bootstrap, identify
from models import get_model, published
from models.errors import ConfigError, DataError
from models.plant import SimOptions, simulate
from models.status import Status

TRUE = published("disc").replace(k=1.0, d=0.03, mu_k=0.28, mu_s=0.45)


@pytest.fixture(scope="module")
def fit_and_boot():
    log = simulate(get_model("disc"), TRUE, np.array([1.0, 20.0]), 20.0, SimOptions(seed=1)).to_log()
    opts = IdentifyOptions(free=("k", "mu_k", "mu_s"), nsub=10, encoder_zero="untwisted")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(log, "disc", published("disc").replace(d=0.03), opts)
        boot = bootstrap(fit, BootstrapOptions(replicates=4))
    return log, fit, boot


@pytest.mark.slow
def test_bootstrap_bias_reproduces_the_fits_actual_error(fit_and_boot):
    """Measured: errors k +0.0057, mu_k +0.0033, mu_s +0.0092; standard errors 0.0010, 0.0004, 0.0007
    (5.6, 8.3, 12.5 of them off); bootstrap bias +0.0053, -0.0033, +0.0031 with sd ~1e-4.  The
    bias at the FITTED point reproduces k's error and mu_k's size; mu_s's pipeline bias changes
    between the truth and the fit (a third of it is reproduced), the documented limitation."""
    _, fit, boot = fit_and_boot
    assert fit.success and boot.success and boot.status is Status.OK, boot.message
    assert boot.replicates.shape == (4, 3) and boot.failures == 0
    err = fit.estimate - np.array([TRUE.k, TRUE.mu_k, TRUE.mu_s])
    assert np.all(np.abs(err) > 4 * fit.stderr)                       # the statistical error bars miss
    assert np.all(boot.error > 2 * fit.stderr)                         # the bootstrap's bars are wider
    assert np.all(np.abs(err[:2]) <= 2 * boot.error[:2])              # and cover k and mu_k
    assert abs(err[2]) <= 4 * boot.error[2] and abs(err[2]) > 10 * fit.stderr[2]
    assert abs(boot.bias[0] - err[0]) <= 0.25 * abs(err[0])           # k's bias reproduced
    np.testing.assert_allclose(boot.error, np.hypot(boot.bias, boot.sd))
    np.testing.assert_allclose(boot.corrected, fit.estimate - boot.bias)
    d = boot.as_dict()
    assert d["replicates"] == 4 and d["status"] == "ok" and d["success"]


@pytest.mark.slow
def test_bootstrap_is_reproducible(fit_and_boot):
    _, fit, boot = fit_and_boot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = bootstrap(fit, BootstrapOptions(replicates=2))
    np.testing.assert_array_equal(again.replicates, boot.replicates[:2])


@pytest.mark.parametrize("kw, match", [
    ({"replicates": 1}, "bootstrap.replicates must be an integer >= 2"),
    ({"force_cutoff": 0.0}, "bootstrap.force_cutoff must be > 0 Hz, got 0.0"),
    ({"speed_cutoff": -1.0}, "bootstrap.speed_cutoff must be > 0 Hz, got -1.0"),
    ({"workers": 0}, "bootstrap.workers must be an integer >= 1"),
    ({"seed": 1.5}, "bootstrap.seed must be an integer"),
    ({"start": "guess"}, "bootstrap.start must be one of initial, fit, got 'guess'"),
])
def test_bad_options(kw, match):
    with pytest.raises(ConfigError, match=match):
        BootstrapOptions(**kw)


def test_bootstrap_needs_a_fit_with_its_problem():
    with pytest.raises(DataError, match="carries its problem"):
        bootstrap(object(), BootstrapOptions(replicates=2))
    with pytest.raises(ConfigError, match="options must be BootstrapOptions"):
        bootstrap(object(), {"replicates": 2})
