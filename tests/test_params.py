"""Parameter sets: published values with provenance, TOML round trip, bad files."""

import math

import pytest

from models.errors import ConfigError
from models.params import PARAM_CLASSES, Rig3Params, load_params, published


def test_published_sets_have_units_bounds_and_sources():
    for name, cls in PARAM_CLASSES.items():
        p = published(name)
        for n in p.names():
            s = p.spec(n)
            assert s.unit and s.source
            assert s.lower <= getattr(p, n) <= s.upper


def test_rig3_published_values_from_the_thesis():
    p = Rig3Params()
    assert (p.k1, p.k2) == (1.1175, 0.3659)                 # eq. 3-7
    assert (p.mu_s, p.mu_k, p.r1) == (0.5, 0.306, 0.047)     # eqs. 3-11, 3-14, 3-10
    assert p.eta == 8.0 and p.Jm == 0.370e-3                 # Table 3.1


def test_toml_round_trip(tmp_path):
    p = Rig3Params().replace(k1=1.2, d2=0.02)
    path = p.save(tmp_path / "fit.toml", note="test")
    q = load_params(path, "rig3")
    assert q == p
    with pytest.raises(ConfigError, match="exists"):
        p.save(path)


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
    ('model = "rig9"\n', r"model must be one of"),
    ('model = "rig3"\nbase = "published"\n[params]\nk1 = "stiff"\n', r"k1 must be a number"),
    ('model = "rig3"\n[params\n', r"not valid TOML"),
])
def test_bad_parameter_files_name_the_field(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_params(_write(tmp_path, text))


def test_model_mismatch_and_missing_file(tmp_path):
    f = _write(tmp_path, 'model = "disc"\nbase = "published"\n')
    with pytest.raises(ConfigError, match="model must be 'rig3'"):
        load_params(f, "rig3")
    with pytest.raises(ConfigError, match="not found"):
        load_params(tmp_path / "nope.toml")


def test_replace_validates():
    with pytest.raises(ConfigError, match="J1"):
        Rig3Params().replace(J1=-1.0)
    with pytest.raises(ConfigError, match="unknown parameter"):
        Rig3Params().replace(J9=1.0)
    assert math.isclose(Rig3Params().J3, 0.02368)


def test_directory_as_parameter_file_is_one_line_error(tmp_path):
    from models.errors import ConfigError
    from models.params import load_params
    with pytest.raises(ConfigError, match=r"cannot read parameter file"):
        load_params(tmp_path)
