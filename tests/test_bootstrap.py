"""Parametric bootstrap of a fit (estimators.bootstrap).

Independent check: on a log of the EXACT stick/slip plant with known truth, the Gauss-Newton
standard errors miss the truth by 7-15 of themselves (quantised encoders, noisy logged force,
regularised model), while the bootstrap's bias, measured on replicates simulated from the
FIT, reproduces the actual error of the fit and its RMS error covers it.
"""

import warnings

import numpy as np
import pytest

from estimators.bootstrap import BootstrapOptions, bootstrap
from estimators.identify import IdentifyOptions, identify
from models.errors import ConfigError, DataError
from models.params import published
from models.rigs import get_model
from models.plant import SimOptions, simulate

TRUE = published("disc").replace(k=1.0, d=0.03, mu_k=0.28, mu_s=0.45)


@pytest.fixture(scope="module")
def fit_and_boot():
    log = simulate(get_model("disc"), TRUE, np.array([1.0, 20.0]), 20.0, SimOptions(seed=1)).to_log()
    opts = IdentifyOptions(free=("k", "mu_k", "mu_s"), eps=0.005, nsub=10)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(log, "disc", published("disc").replace(d=0.03), opts)
        boot = bootstrap(fit, log, opts, BootstrapOptions(replicates=4))
    return log, opts, fit, boot


def test_bootstrap_bias_reproduces_the_fits_actual_error(fit_and_boot):
    _, _, fit, boot = fit_and_boot
    assert fit.success and boot.success and boot.replicates.shape == (4, 3) and boot.failures == 0
    err = fit.estimate - np.array([TRUE.k, TRUE.mu_k, TRUE.mu_s])
    assert np.all(np.abs(err) > 5 * fit.stderr)              # the statistical error bars miss
    assert np.all(np.abs(err) <= 2 * boot.error)             # the bootstrap's RMS error covers
    assert np.all(np.abs(boot.bias - err) <= 0.25 * np.abs(err) + 2 * boot.sd)
    np.testing.assert_allclose(boot.error, np.hypot(boot.bias, boot.sd))
    np.testing.assert_allclose(boot.corrected, fit.estimate - boot.bias)


def test_bootstrap_is_reproducible(fit_and_boot):
    log, opts, fit, boot = fit_and_boot
    again = bootstrap(fit, log, opts, BootstrapOptions(replicates=2))
    np.testing.assert_array_equal(again.replicates, boot.replicates[:2])


@pytest.mark.parametrize("kw, match", [
    ({"replicates": 1}, "bootstrap.replicates must be an integer >= 2"),
    ({"force_cutoff": 0.0}, "bootstrap.force_cutoff must be a frequency > 0 Hz"),
    ({"workers": 0}, "bootstrap.workers must be an integer >= 1"),
    ({"seed": 1.5}, "bootstrap.seed must be an integer"),
    ({"start": "guess"}, "bootstrap.start must be .initial. or .fit."),
])
def test_bad_options(kw, match):
    with pytest.raises(ConfigError, match=match):
        BootstrapOptions(**kw)


def test_log_count_must_match_the_fit(fit_and_boot):
    log, opts, fit, _ = fit_and_boot
    with pytest.raises(DataError, match="the fit used 1 log"):
        bootstrap(fit, [log, log], opts, BootstrapOptions(replicates=2))
