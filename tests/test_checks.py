"""One vocabulary for options (models/checks.py): the message of every kind of bad value."""

from dataclasses import dataclass

import pytest

from models.checks import choice, flag, integer, names, number, options_from_mapping, prefix
from models.errors import ConfigError


@pytest.mark.parametrize("call, match", [
    (lambda: number("x", "a.b", lo=0, lo_open=True, unit="s"), r"^a\.b must be a finite number > 0 s, got 'x'$"),
    (lambda: number(float("nan"), "a.b"), r"^a\.b must be a finite number, got nan$"),
    (lambda: number(True, "a.b"), r"^a\.b must be a finite number, got True$"),
    (lambda: number(-1, "a.b", lo=0, lo_open=True, unit="rad/s"), r"^a\.b must be > 0 rad/s, got -1$"),
    (lambda: number(2.0, "a.b", lo=0, hi=1, lo_open=True), r"^a\.b must be in \(0, 1\], got 2\.0$"),
    (lambda: number(1.0, "a.b", hi=1, hi_open=True), r"^a\.b must be < 1, got 1\.0$"),
    (lambda: integer(0, "a.n", lo=1), r"^a\.n must be an integer >= 1, got 0$"),
    (lambda: integer(1.5, "a.n"), r"^a\.n must be an integer, got 1\.5$"),
    (lambda: integer(11, "a.n", lo=0, hi=10, unit="samples"), r"^a\.n must be an integer in \[0, 10\] samples, got 11$"),
    (lambda: flag("yes", "a.f"), r"^a\.f must be true or false, got 'yes'$"),
    (lambda: flag(1, "a.f", none=True), r"^a\.f must be true or false, or unset, got 1$"),
    (lambda: choice("lm", "a.solver", ("gn", "ipopt")), r"^a\.solver must be one of gn, ipopt, got 'lm'$"),
    (lambda: names(3, "a.free"), r"^a\.free must be a list of names, got 3$"),
    (lambda: names("k1,k2", "a.free"), r"^a\.free must be a list of names, got 'k1,k2'$"),
    (lambda: names([], "a.free", nonempty=True), r"^a\.free must be a non-empty list of names, got \[\]$"),
    (lambda: names(["k", "k"], "a.free", unique=True), r"^a\.free lists 'k' twice, got \['k', 'k'\]$"),
])
def test_one_message_per_kind_of_bad_value(call, match):
    with pytest.raises(ConfigError, match=match):
        call()


def test_good_values_come_back_typed():
    assert number(1, "a", lo=0) == 1.0 and isinstance(number(1, "a"), float)
    assert number(None, "a", none=True) is None and integer(None, "a", none=True) is None
    assert integer(3, "a", lo=1) == 3 and flag(False, "a") is False and choice("gn", "a", ("gn",)) == "gn"
    assert names("k1, k2", "a", split=True) == ("k1", "k2")


@dataclass(frozen=True, kw_only=True)
class _Opts:
    gain: float = 1.0
    steps: int = 2

    def __post_init__(self):
        w = prefix("opts")
        number(self.gain, f"{w}.gain", lo=0.0, unit="N m s")
        integer(self.steps, f"{w}.steps", lo=1)


def test_options_from_mapping_names_the_table_and_its_fields():
    assert options_from_mapping(_Opts, {"gain": 2.0}, "s.toml: ctl") == _Opts(gain=2.0)
    with pytest.raises(ConfigError, match=r"^s\.toml: ctl\.gain must be >= 0 N m s, got -1$"):
        options_from_mapping(_Opts, {"gain": -1}, "s.toml: ctl")
    with pytest.raises(ConfigError, match=r"^s\.toml: ctl\.gian: unknown key for kind 'k'; expected one of gain, steps$"):
        options_from_mapping(_Opts, {"gian": 1}, "s.toml: ctl", kind="k")
    with pytest.raises(ConfigError, match=r"^s\.toml: ctl must be a table, got 3$"):
        options_from_mapping(_Opts, 3, "s.toml: ctl")
    # built directly, the class names its fields under its own default
    with pytest.raises(ConfigError, match=r"^opts\.steps must be an integer >= 1, got 0$"):
        _Opts(steps=0)


def test_a_foreign_options_class_still_names_the_table_and_its_field():
    @dataclass(frozen=True)
    class Foreign:
        x: int = 0

        def __post_init__(self):
            if self.x < 0:
                raise ConfigError("x must be >= 0")
            if self.x == 3:
                raise ConfigError("three is unlucky")
            if self.x > 5:
                raise ValueError("too big")

    # a message opening with one of its fields names that field under the table; any other names the table
    with pytest.raises(ConfigError, match=r"^t\.x must be >= 0$"):
        options_from_mapping(Foreign, {"x": -1}, "t")
    with pytest.raises(ConfigError, match=r"^t: three is unlucky$"):
        options_from_mapping(Foreign, {"x": 3}, "t")
    with pytest.raises(ConfigError, match=r"^t: ValueError: too big$"):
        options_from_mapping(Foreign, {"x": 9}, "t")
