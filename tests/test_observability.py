"""Observability of the estimators' model: analytic checks, and the verdicts on rig3 and other rigs.

The physics behind the rig3 verdicts (estimators/online/observability.py): with the encoders
zeroed at power-on, the twist's level, the friction load factor and a torque-sensor offset
trade off exactly at steady sliding; the friction's variation with speed separates them.
"""

import math

import numpy as np
import pytest

from estimators.base import EstimatorContext
from estimators.online.ekf import EKF
from estimators.online.model import build_estimation_model
from estimators.online.observability import compress_channels, linearisation_function, observability
from estimators.online.options import EKFOptions
from models import get_model
from models.errors import ConfigError
from models.status import Status

M = get_model("rig3")
P3 = M.published()
U = np.array([math.pi, 20.0, 0.0])
ENCODERS = ["theta1", "theta2", "theta3", "omega1", "omega2", "omega3"]


def steady(em, n=100):
    """A constant trajectory at rig3's steady sliding (30 rpm, 20 N)."""
    xs = em.full_state(M.steady_sliding(U, P3))
    return np.tile(xs, (n, 1)), np.tile(U, (n, 1))


def em_of(**kw):
    return build_estimation_model(M, P3, EKFOptions(**kw), 0.01)


def test_singular_values_are_those_of_the_stacked_matrix():
    """At steady sliding (constant A, C; no body near rest) the reported singular values are
    those of [C; C A; C A^2; ...] with rows divided by the noise std and columns multiplied by
    the prior std, built here by hand."""
    em = em_of(channels=ENCODERS + ["motor_torque"], augment=[], angles="absolute")
    X, UH = steady(em, 30)
    rep = observability(em, X, UH)
    A, C = (np.array(v) for v in linearisation_function(em)(X[0], X[0], U, em.p))
    W = np.diag(1 / np.sqrt(em.r))
    S = np.diag(np.sqrt(np.diag(em.P0)))
    O = np.vstack([W @ C @ np.linalg.matrix_power(A, k) @ S for k in range(30)])
    s = np.linalg.svd(O, compute_uv=False)
    np.testing.assert_allclose(rep.singular_values, s, rtol=1e-6, atol=1e-9 * s[0])
    assert rep.condition == pytest.approx(s[0] / s[-1], rel=1e-6)


def test_the_steady_sliding_hinge_is_an_exact_null_direction():
    """At steady sliding, shifting the twist, its power-on value and the R1 load factor together
    (and the PI state and current that hold the new level) is an equilibrium that no encoder
    sees: an exact null direction (the derivation is in the module docstring).  Without the
    load factor the friction level is known and the direction disappears."""
    em = em_of(channels=ENCODERS)
    with_load = observability(em, *steady(em, 100))
    s = with_load.singular_values
    assert s[-1] <= 1e-12 * s[0]
    assert not with_load.twist_observable
    em2 = em_of(channels=ENCODERS, augment=[])
    without = observability(em2, *steady(em2, 100))
    assert without.twist_observable


def test_default_rig3_is_observable_along_its_start_up():
    """The construction-time check of the default configuration (all encoders + motor torque,
    angles zeroed, load:pin1 and offset:motor_torque): the twist is observable along the
    start-up at the operating point, where the friction varies."""
    est = EKF(EKFOptions(compile=False), EstimatorContext(M, P3, 0.01))
    rep = est.observability
    assert rep.twist_observable and rep.observable, rep.message
    assert rep.regime == "start-up at the operating point"
    assert np.all(rep.twist_std < 0.01)
    assert rep.message.startswith("observable at start-up")
    assert "channels theta1..3, omega1..3, motor_torque" in rep.message


@pytest.mark.slow
def test_encoders_only_zeroed_are_not_observable_at_steady_sliding_and_say_what_trades_off():
    """Encoders only, zeroed at power-on: at steady sliding the twist trades off against the
    power-on twist and the R1 load factor; the message names them and the torque channel."""
    est = EKF(EKFOptions(channels=ENCODERS, compile=False), EstimatorContext(M, P3, 0.01))
    rep = est.observability_steady
    assert not rep.twist_observable and not rep.observable
    assert rep.status is Status.WARNING
    assert rep.message.startswith("twist not observable at steady sliding: twist_shaft2 trades off against")
    for name in ("load:pin1", "zero:twist_shaft2", "channels theta1..3, omega1..3", "add motor_torque"):
        assert name in rep.message, rep.message
    weak = rep.weak[0]
    assert weak.singular_value < 1.0 and {"twist_shaft2", "zero:twist_shaft2", "load:pin1"} <= {n for n, _ in weak.terms}
    # what makes it observable: the torque channel (offset known), or absolute angles
    assert "observable at steady sliding" in EKF(EKFOptions(compile=False, augment=["load:pin1"]),
                                                 EstimatorContext(M, P3, 0.01)).observability_message
    assert EKF(EKFOptions(channels=ENCODERS, angles="absolute", compile=False),
               EstimatorContext(M, P3, 0.01)).observability_steady.twist_observable


def test_default_is_not_observable_at_steady_sliding_because_of_the_offset_state():
    """The price of offset:motor_torque: at steady sliding the torque channel's level is no
    longer the shaft torque, and the twist trades off like with encoders only."""
    est = EKF(EKFOptions(compile=False), EstimatorContext(M, P3, 0.01))
    rep = est.observability_steady
    assert not rep.twist_observable
    assert "offset:motor_torque" in rep.message and "load:pin1" in rep.message
    hint = rep.message[rep.message.index("drop"):]
    assert "offset:motor_torque" in hint and "load:pin1" in hint
    # and in one line with the start-up verdict
    assert est.observability_message.count("; ") >= 1 and "\n" not in est.observability_message


def test_stick_phases_inform_nothing_through_the_stuck_body():
    """Along our exact plant's stick-slip, where R1 sits at rest, its friction is an unknown
    constraint torque: the analysis gets 3-5x less twist information than by trusting the
    regularised model's creep (measured 5.6 / 17 mrad against 1.1 / 3.4 mrad)."""
    from models.plant import SimOptions, simulate

    sim = simulate(M, P3, U, 1.5, SimOptions(seed=1))
    assert np.mean(sim.x[:, 2] == 0.0) > 0.3                      # R1 stuck a third of the window
    em = em_of()
    X = np.array([em.full_state(x) for x in sim.x])
    UH = np.tile(U, (len(X), 1))
    honest = observability(em, X, UH)
    trusting = observability(em, X, UH, stick_speed=0.0)
    assert np.all(honest.twist_std > 2 * trusting.twist_std), (honest.twist_std, trusting.twist_std)


def test_observability_along_a_logged_trajectory_and_bad_input():
    est = EKF(EKFOptions(compile=False, check_observability=False), EstimatorContext(M, P3, 0.01))
    assert est.observability is None
    xs = M.steady_sliding(U, P3)
    rep = est.observability_along(np.tile(xs, (50, 1)), np.tile(U, (50, 1)))   # rig states: augmented filled in
    assert rep.samples == 50 and not rep.twist_observable and rep.regime == "the given trajectory"
    d = rep.as_dict()
    assert d["twist_observable"] is False and set(d["twist_std_rad"]) == {"twist_shaft1", "twist_shaft2"}
    with pytest.raises(ConfigError, match=r"observability needs X of shape \(N, 11\)"):
        observability(est.em, np.zeros((5, 3)), np.zeros((5, 3)))


def test_channel_lists_are_compressed_for_messages():
    assert compress_channels(["theta1", "theta2", "theta3", "omega1", "omega3", "motor_torque"]) == \
        "theta1..3, omega1, omega3, motor_torque"
    assert compress_channels(["theta_drive", "theta_bit"]) == "theta_drive, theta_bit"


def test_disc_rig_verdicts():
    """The one-disc rig: its load factor and the spring's twist at power-on trade off at
    steady sliding; with the friction level known the twist is observable."""
    disc = get_model("disc")
    c = EstimatorContext(disc, disc.published(), 0.01)
    assert not EKF(EKFOptions(compile=False), c).observability_steady.twist_observable
    assert EKF(EKFOptions(compile=False, augment=[]), c).observability_steady.twist_observable
