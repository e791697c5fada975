"""Scale-free metric defaults (issue 18 item 5): every default of mitigate/metrics/ that carries a
unit comes from the scenario -- a torque drive's programmed speed is its [control] speed, a measured
stuck threshold comes from the encoder or the programmed speed, never rig3's 0.05 rad/s."""

import json
import math

import numpy as np
import pytest

from mitigate import metrics as M
from mitigate.cli import main
from mitigate.scenario import make_scenario
from models.sensors import encoder_step


def test_a_torque_drives_programmed_speed_is_the_scenarios_target():
    """rig2's operating point says 1 rad/s; [control] speed says 2 rad/s: the metrics (severity, the
    speed band, the stuck threshold) must measure against the speed the laws aim at."""
    t = np.linspace(0.0, 5.0, 6)
    sc = make_scenario(name="t", model="rig2", duration=5.0, inputs={"motor_torque": 0.0}, estimator="fd",
                       controllers=["softspeed"], control={"speed": "2 rad/s"})
    np.testing.assert_allclose(M.programmed_speed(sc, t), 2.0)
    sc1 = make_scenario(name="t", model="rig2", duration=5.0, inputs={"motor_torque": 0.0}, estimator="fd",
                        controllers=["softspeed"])
    np.testing.assert_allclose(M.programmed_speed(sc1, t), 1.0)       # no target: the rig file's operating point


def test_the_measured_stuck_threshold_comes_from_the_encoder_or_the_programme():
    sc = make_scenario(name="t", duration=1.0, inputs={"omega_ref": "30 rpm", "n1": 20.0}, controllers=["pi"])
    ch, thr = M.measured_stuck_speed(sc, math.pi)
    s = sc.model.sensor_of(ch)
    assert s.kind == "encoder" and thr == pytest.approx(0.5 * encoder_step(s) / sc.dt)
    assert M.measured_stuck_speed(sc, math.pi, 0.2) == (ch, 0.2)
    with pytest.raises(TypeError):
        M.stuck_fraction(np.zeros(3))                  # no rig3 default left


def test_simulate_reports_the_threshold_it_used(tmp_path, capsys):
    sc = tmp_path / "s.toml"
    sc.write_text('[scenario]\nname = "s"\nmodel = "rig3"\nduration = 1.0\nseed = 2\n[inputs]\n'
                  'omega_ref = "30 rpm"\nn1 = 20.0\n')
    assert main(["simulate", str(sc), "--out", str(tmp_path / "o"), "--no-plot", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    m = make_scenario(name="t", duration=1.0, inputs={"omega_ref": "30 rpm", "n1": 20.0}, controllers=["pi"]).model
    s = m.sensor_of(m.speed_channel(m.objective_body))
    assert doc["stuck_speed_measured"] == pytest.approx(0.5 * encoder_step(s) / 0.01)
    assert doc["stuck_speed_measured"] != pytest.approx(0.05)
    assert 0.0 <= doc["stuck_fraction_measured"] <= 1.0
