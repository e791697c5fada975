"""A new friction law is one function plus one registry entry (issue 19's target).

The law below is defined HERE and nowhere else: a Gaussian Stribeck curve with a viscous part,
its parameters named unlike any shipped law's (``f_static``, ``f_coulomb``, ``w_char``,
``c_visc``) so that nothing can recognise it by name.  Its parameter roles (static and kinetic
level, decay speed, viscous) are all the workbench needs: identification's data-derived guess
regresses on the parameters the law is linear in, its ``kinetic <= static`` constraint pairs the
two levels, the EKF tracks the rig, and D-OSKIL scales its gain by the kinetic level.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from models import friction as fr
from models import get_model
from models.plant import SimOptions, simulate

RIG3 = Path(__file__).resolve().parents[1] / "models" / "rigs" / "rig3.toml"


def gauss_stribeck(v_abs, scale, *, f_static, f_coulomb, w_char, c_visc):
    """``N r [f_c + (f_s - f_c) exp(-(|w|/w_c)^2) + c_v |w|]``: a Gaussian Stribeck curve plus viscous."""
    exp = ca.exp if isinstance(v_abs, (ca.SX, ca.MX, ca.DM)) else np.exp
    return scale * (f_coulomb + (f_static - f_coulomb) * exp(-(v_abs / w_char) ** 2) + c_visc * v_abs)


LAW = fr.FrictionLaw("gauss_stribeck", gauss_stribeck,
                     (fr.Param("f_static", "level", "static level", 0.0, role="static"),
                      fr.Param("f_coulomb", "level", "kinetic level", 0.0, role="kinetic"),
                      fr.Param("w_char", "speed", "characteristic speed", 0.0, role="decay_speed"),
                      fr.Param("c_visc", "level_slowness", "viscous part", 0.0, role="viscous")),
                     doc="Gaussian Stribeck curve plus viscous friction", reference="this test")


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    fr.register(LAW)
    text = RIG3.read_text().replace('name = "rig3"', 'name = "rig3_gauss"').replace('law = "stribeck"',
                                                                                 'law = "gauss_stribeck"')
    text = text.replace('mu_s = "mu_s"', 'f_static = "mu_s"').replace('mu_k = "mu_k"', 'f_coulomb = "mu_k"')
    text = text.replace('v_s = "v_s"', 'w_char = "v_s"\nc_visc = "cv"')
    text = text.replace("[parameters]\n", '[parameters]\ncv = { value = 0.01, unit = "s/rad", source = "this test" }\n')
    path = tmp_path_factory.mktemp("law") / "rig3_gauss.toml"
    path.write_text(text)
    yield get_model(path)
    fr.LAWS.pop(LAW.name)


@pytest.fixture(scope="module")
def log(rig):
    true = rig.published().replace(mu_k=0.28, mu_s=0.46)
    r = simulate(rig, true, np.array([1.0, 20.0, 0.0]), 12.0, SimOptions(seed=3))
    assert r.success and np.mean(r.state("omega_R1") == 0.0) > 0.1     # stick-slip in the log
    return true, r.to_log()


def test_the_law_knows_its_roles(rig):
    law = rig.law("pin1")
    assert law is LAW and law.level_order == ("f_coulomb", "f_static")
    assert law.linear_params == ("f_static", "f_coulomb", "c_visc") and law.with_role("kinetic") == "f_coulomb"


@pytest.mark.slow
def test_identification_fits_the_new_law(rig, log):
    from estimators.identify import IdentifiabilityWarning, IdentifyOptions, identify, initial_guess

    true, lg = log
    # the guess regresses the torque balance behind motor_torque on the law's linear parameters
    g = initial_guess(rig, lg, ("mu_k", "mu_s"))
    assert "mu_k" in g.values and g.values["mu_k"] == pytest.approx(0.28, rel=0.15), g.notes
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        fit = identify(lg, rig, rig.published(), IdentifyOptions(free=("mu_k", "mu_s"), encoder_zero="untwisted"))
    assert fit.success, fit.message
    # the kinetic <= static constraint comes from the law's roles
    assert any("mu_k <= mu_s" in c.text for c in fit.problem.constraints)
    est = dict(zip(fit.names, fit.estimate))
    assert est["mu_k"] == pytest.approx(0.28, rel=0.05) and est["mu_s"] == pytest.approx(0.46, rel=0.05)


def test_ekf_tracks_the_rig_with_the_new_law(rig):
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.scenario import make_scenario

    sc = make_scenario(name="gauss", model=rig, duration=6.0, inputs={"omega_ref": 1.0, "n1": 20, "n2": 0},
                       controllers=["pi"], estimator="ekf")
    r = run_closed_loop(sc, make_controller(sc.controllers[0], context_for(sc, 0)))
    assert r.status.success and r.estimator_counts["failures"] == 0
    i, j = r.xhat_names.index("omega_R1"), rig.speed_index("R1")
    late = r.t > 3.0
    assert np.sqrt(np.mean((r.xhat[late, i] - r.x[late, j]) ** 2)) < 0.1 * np.max(np.abs(r.x[late, j]))


def test_doskil_uses_the_kinetic_level_of_the_new_law(rig):
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.controllers.tuning import tuning_for
    from mitigate.scenario import make_scenario

    sc = make_scenario(name="gauss_dk", model=rig, duration=4.0, inputs={"omega_ref": 1.0, "n1": 20, "n2": 0},
                       controllers=["doskil"], estimator="fd", control_start=1.0)
    dk = make_controller(sc.controllers[0], context_for(sc, 0))
    p = rig.published()
    assert dk.gain == pytest.approx(2 * tuning_for(rig, p).Z / (p["r2"] * p["mu_k"]), rel=1e-12)
    r = run_closed_loop(sc, dk)
    assert r.status.success and r.controller_counts["failures"] == 0
    assert np.max(r.commands["n2"][r.t > 1.5]) > 0.0        # it acts on the brake
