"""Bodies that cannot be simulated are refused at rig-file parse time with one line naming the
body (or the connection) and the cause (issue 18 item 9, issue 20 "Sizes and numbers").

Before: a massless body ended as "simulation of 'x' failed: non-finite state at t = 0.010 s"
or an internal LinAlgError; ``inertia = 0.0`` with its parameter still declared said
"parameters.JB: declared but not used"; a stiffness of 1e308 gave RuntimeWarnings, then an
internal ValueError.
"""

from __future__ import annotations

import subprocess
import sys

from pathlib import Path

import pytest

from models import get_model
from models.errors import ConfigError



def _text():
    """The user's DC-motor rig (its armature inductance is 1 mH)."""
    return (Path(__file__).resolve().parent / "data" / "small_motor.toml").read_text()


def _write(tmp_path, text):
    path = tmp_path / "tworig.toml"
    path.write_text(text)
    return path


def test_massless_body_constant_is_refused_naming_the_body(tmp_path):
    text = _text().replace('[bodies.B]\ninertia = "JB"', '[bodies.B]\ninertia = 0.0')
    with pytest.raises(ConfigError, match=r"^tworig\.toml: bodies\.B\.inertia: 0 kg m\^2 and no motor drives it: "
                                          r"a massless body"):
        get_model(_write(tmp_path, text))


def test_massless_body_names_the_body_not_the_unused_parameter(tmp_path):
    # JB is still declared: the cause is the massless body, not an unused parameter
    text = _text().replace('[bodies.B]\ninertia = "JB"', '[bodies.B]\ninertia = "0 kg m^2"')
    assert "JB = {" in text
    with pytest.raises(ConfigError, match=r"bodies\.B\.inertia: 0 kg m\^2 and no motor drives it"):
        get_model(_write(tmp_path, text))


def test_massless_body_through_a_parameter(tmp_path):
    text = _text().replace('JB = { value = 0.012', 'JB = { value = 0.0')
    with pytest.raises(ConfigError, match=r"bodies\.B\.inertia: parameter 'JB' = 0 kg m\^2 and no motor drives it"):
        get_model(_write(tmp_path, text))


def test_a_motor_reflected_onto_a_zero_inertia_body_is_fine(tmp_path):
    # rig3's R3 has inertia 0 and the motor's rotor reflected onto it (thesis eq. 3-3)
    text = _text().replace('[bodies.A]\ninertia = "JA"', '[bodies.A]\ninertia = 0.0').replace(
        'JA = { value = 0.01, unit = "kg m^2" }\n', '')
    m = get_model(_write(tmp_path, text))
    assert m.inertia("A", m.published()) == pytest.approx(30.0 ** 2 * 2e-6)


@pytest.mark.parametrize("value", ["1e308", "1e30"])
def test_absurd_stiffness_is_refused_in_one_line(tmp_path, value):
    text = _text().replace('k = { value = 0.5, unit = "N m/rad" }', f'k = {{ value = {value}, unit = "N m/rad" }}')
    with pytest.raises(ConfigError, match=r"connections\.shaft\.stiffness: 1e\+\d+ N m/rad \(parameter 'k'\) on A "
                                          r".* gives a rate of .* 1/s \(at most 1e\+08\)"):
        get_model(_write(tmp_path, text))


def test_absurd_damping_constant_is_refused(tmp_path):
    text = _text().replace('damping = "d"', 'damping = 1e300').replace('d = { value = 0.005, unit = "N m s/rad" }\n', '')
    with pytest.raises(ConfigError, match=r"connections\.shaft\.damping: 1e\+300 N m s/rad on A"):
        get_model(_write(tmp_path, text))


@pytest.mark.slow
def test_cli_gives_one_line_and_exit_2_for_a_massless_body(tmp_path):
    text = _text().replace('[bodies.B]\ninertia = "JB"', '[bodies.B]\ninertia = 0.0')
    path = _write(tmp_path, text)
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "modal", "--model", str(path)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "bodies.B.inertia" in lines[0] and "massless body" in lines[0], r.stderr
