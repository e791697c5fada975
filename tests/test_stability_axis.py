"""The stability map's force axis is the rig's actuated input over its rated range (issue 28, item 5).

Before, ``mitigate modal`` mapped the first contact's input over 0-40 N: on a user's bench that was a
Coulomb caliper rated to 800 N, whose force has no effect on the stability of sliding.  Now the axis
is a servo's input over ``[n_min, n_max]`` (:func:`models.stability.map_axis`), the output says which input
and range, and whether that input changes the stability at all.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from models import get_model
from models.errors import ConfigError
from models.stability import map_axis, stability_map, stribeck_onset

ROOT = Path(__file__).resolve().parents[1]


def caliper_bench(tmp_path) -> Path:
    """The user's bench, written on the shipped one-disc rig: a Coulomb caliper (the FIRST contact,
    servo-actuated, rated to 800 N) and the Stribeck pin, whose force n1 is logged, not actuated."""
    t = (ROOT / "models/rigs/disc.toml").read_text()
    for old, new in [
        ('operating_point = { omega3 = "30 rpm", n1 = "20 N" }',
         'operating_point = { omega3 = "30 rpm", n_cal = "100 N", n1 = "20 N" }'),
        ('name = "disc"', 'name = "caliper_bench"'),
        ("r = { value = 0.047", 'mu_c = { value = 0.4, max = 5, source = "ASSUMPTION", doc = "caliper pads" }\n'
                                "r = { value = 0.047"),
        ("[contacts.pin]", '[contacts.caliper]\nbody = "disc"\nlaw = "coulomb"\nnormal = "n_cal"\nradius = "r"\n'
                           'mu_k = "mu_c"\n\n[contacts.pin]'),
        ("[sensors.enc1]", '[actuators.caliper_servo]\nkind = "servo"\ninput = "n_cal"\nn_min = "0 N"\n'
                           'n_max = "800 N"\nrate_max = "2 kN/s"\ntau = "20 ms"\n\n[sensors.enc1]'),
    ]:
        assert old in t, old
        t = t.replace(old, new, 1)
    p = tmp_path / "caliper_bench.toml"
    p.write_text(t)
    return p


def test_the_axis_is_the_actuated_input_over_its_rating(tmp_path):
    a = map_axis("rig3")                              # servo2 on the R2 pin, 0-40 N (not N1, the process load)
    assert (a.input, a.lo, a.hi) == ("n2", 0.0, 40.0) and "servo2" in a.source
    w = map_axis("drillstring_motor")
    act = get_model("drillstring_motor").actuator(w.input)
    assert (w.lo, w.hi) == (act.n_min, act.n_max)
    d = map_axis("disc")                              # no actuator: its operating force doubled, and it says so
    assert (d.input, d.lo, d.hi) == ("n1", 0.0, 40.0) and d.source.startswith("no actuator sets it")
    b = map_axis(str(caliper_bench(tmp_path)))
    assert (b.input, b.lo, b.hi) == ("n_cal", 0.0, 800.0)
    assert map_axis(str(caliper_bench(tmp_path)), input="n1").hi == 40.0
    with pytest.raises(ConfigError, match="normal-force input of rig 'disc' \\(n1\\), got 'omega3'"):
        map_axis("disc", input="omega3")
    with pytest.raises(ConfigError, match="input must be a normal-force input"):
        stability_map("disc", None, [1.0], [1.0], input="omega3")


def test_a_coulomb_caliper_does_not_move_stability_and_the_stribeck_pin_does_at_the_analytic_onset(tmp_path):
    """On the bench, the caliper's force leaves every eigenvalue where it was (a Coulomb law's slope is
    zero while sliding); the Stribeck pin's force destabilises sliding at the single-DOF onset
    N* = d v_s exp(w/v_s) / (r (mu_s - mu_k)) (exact for one disc on a damped spring to a held end)."""
    rig = get_model(str(caliper_bench(tmp_path)))
    p = rig.published()
    w = math.pi
    M = stability_map(rig, p, [0.0, 400.0, 800.0], [1.0, w, 6.0])          # default axis: the caliper
    assert np.max(np.ptp(M, axis=0)) <= 1e-3 * np.max(np.abs(M))
    n_star = stribeck_onset(p.mu_s, p.mu_k, p.v_s, p.r, w, p.d)            # 54.2 N
    assert 40.0 < n_star < 70.0
    M1 = stability_map(rig, p, [0.97 * n_star, 1.03 * n_star], [w], input="n1")
    assert M1[0, 0] < 0 < M1[1, 0]


@pytest.mark.slow
def test_modal_says_which_input_and_range_it_mapped(tmp_path, capsys):
    from mitigate.cli import main
    bench = caliper_bench(tmp_path)
    assert main(["modal", "--model", str(bench), "--variant", "closed", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "stability map: n_cal over 0-800 N (the rated range of actuator 'caliper_servo')" in out
    assert "n_cal does not change the stability of sliding over this range" in out
    assert main(["modal", "--model", str(bench), "--variant", "closed", "--map-input", "n1", "--json",
                 "--out", str(tmp_path / "o1")]) == 0
    sm = json.loads(capsys.readouterr().out)["stability_map"]
    assert sm["load"] == "n1" and sm["range"] == [0.0, 40.0] and sm["load_changes_stability"] is True
    assert sm["range_source"] == "no actuator sets it: 0 to twice its operating point (20 N)"
    # a bad --map-input is refused before anything is written
    assert main(["modal", "--model", str(bench), "--map-input", "omega3", "--out", str(tmp_path / "o2")]) == 2
    assert "--map-input must be a normal-force input" in capsys.readouterr().err
    assert not (tmp_path / "o2").exists()
