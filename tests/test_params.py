"""Parameter sets: published values with provenance, TOML round trip, bad files."""

import math

import pytest

from models import get_model, load_params, published, shipped_rigs
from models.errors import ConfigError


def test_published_sets_have_units_bounds_and_sources():
    for name in shipped_rigs():
        p = published(name)
        for n in p.names():
            s = p.spec(n)
            assert s.unit and s.source, (name, n)
            assert s.lower <= p[n] <= s.upper


def test_rig3_published_values_from_the_thesis():
    p = published("rig3")
    assert (p.k1, p.k2) == (1.1175, 0.3659)                 # eq. 3-7
    assert (p.mu_s, p.mu_k, p.r1) == (0.5, 0.306, 0.047)     # eqs. 3-11, 3-14, 3-10
    assert p.eta == 8.0 and p.Jm == 0.370e-3                 # Table 3.1
    assert (p.d1, p.d2) == (0.02145, 0.01595)                # eq. 3-9
    # the sensors' calibration is part of the set (nominal: no offset, unit gain)
    assert p.motor_torque_offset == 0.0 and p.motor_torque_gain == 1.0 and p.n1_offset == 0.0


def test_toml_round_trip(tmp_path):
    p = published("rig3").replace(k1=1.2, d2=0.02, motor_torque_offset=0.05)
    path = p.save(tmp_path / "fit.toml", note="test")
    q = load_params(path, "rig3")
    assert q == p
    with pytest.raises(ConfigError, match="exists"):
        p.save(path)


def test_quantity_strings_are_converted(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text('model = "rig3"\nbase = "published"\n[params]\nk1 = "1117.5 N mm/rad"\nJ1 = "288.8 kg cm^2"\n')
    p = load_params(f)
    assert p.k1 == pytest.approx(1.1175) and p.J1 == pytest.approx(0.02888)


def _write(tmp_path, text):
    f = tmp_path / "p.toml"
    f.write_text(text)
    return f


@pytest.mark.parametrize("text, match", [
    ('model = "rig3"\nbase = "published"\n[params]\nk9 = 1.0\n', r"params\.k9: unknown parameter"),
    ('model = "rig3"\n[params]\nk1 = 1.0\n', r"missing field\(s\) J1"),
    ('model = "rig3"\nbase = "published"\n[params]\nJ1 = -0.02\n', r"J1 must be > 0"),
    ('model = "rig3"\nbase = "published"\n[params]\nJ2 = 0.0\n', r"J2 must be > 0"),
    ('model = "rig3"\nbase = "published"\n[params]\nk1 = nan\n', r"k1 must be finite"),
    ('model = "rig3"\nbase = "published"\n[params]\nk1 = inf\n', r"k1 must be finite"),
    ('model = "rig3"\nbase = "published"\n[bounds]\nk1 = [2.0, 0.5]\n', r"bounds\.k1 must be \[lower, upper\]"),
    ('model = "rig3"\nbase = "published"\n[bounds]\nk1 = [0.5]\n', r"bounds\.k1"),
    ('model = "rig3"\nbase = "published"\nextra = 1\n', r"extra: unknown key"),
    ('model = "rig9"\n', r"model must be a shipped rig"),
    ('model = "rig3"\nbase = "published"\n[params]\nk1 = "stiff"\n', r"k1 must be a number"),
    ('model = "rig3"\nbase = "published"\n[params]\nk1 = "1.1 N m"\n', r"does not convert to a stiffness"),
    ('model = "rig3"\n[params\n', r"not valid TOML"),
])
def test_bad_parameter_files_name_the_field(tmp_path, text, match):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as exc:
        load_params(path)
    # one line, opening with the file (the where is passed down, not re-prefixed afterwards)
    assert str(exc.value).startswith(f"{path}: ") and "\n" not in str(exc.value)


def test_model_mismatch_and_missing_file(tmp_path):
    f = _write(tmp_path, 'model = "disc"\nbase = "published"\n')
    with pytest.raises(ConfigError, match="model must be 'rig3'"):
        load_params(f, "rig3")
    with pytest.raises(ConfigError, match="not found"):
        load_params(tmp_path / "nope.toml")


def test_replace_validates():
    p = published("rig3")
    with pytest.raises(ConfigError, match="J1"):
        p.replace(J1=-1.0)
    with pytest.raises(ConfigError, match="unknown parameter"):
        p.replace(J9=1.0)
    assert math.isclose(p.eta ** 2 * p.Jm, 0.02368)
    with pytest.raises(AttributeError, match="frozen"):
        p.k1 = 2.0


def test_parameter_file_can_name_a_rig_file(tmp_path):
    rig = get_model("disc")
    src = open(rig.spec.path).read()
    (tmp_path / "mydisc.toml").write_text(src.replace('name = "disc"', 'name = "mydisc"'))
    f = _write(tmp_path, 'model = "mydisc.toml"\nbase = "published"\n[params]\nk = 2.0\n')
    p = load_params(f)
    assert p.k == 2.0 and get_model(p.model).name == "mydisc"


def test_directory_as_parameter_file_is_one_line_error(tmp_path):
    with pytest.raises(ConfigError, match=r"cannot read parameter file"):
        load_params(tmp_path)
