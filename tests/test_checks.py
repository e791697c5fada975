"""One vocabulary for options (models/checks.py): the message of every kind of bad value."""

import math
from dataclasses import dataclass

import pytest

from models.checks import (check_options, choice, flag, integer, names, number, option, options_from_mapping, prefix,
                           where_field)
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
    with pytest.raises(ConfigError, match=r"^s\.toml: ctl\.gian: unknown key for kind 'k' \(did you mean 'gain'\?\); expected one of gain, steps$"):
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


# ----------------------------------------------------------------------------- option(): every kind declared once
def _below_ten(v, where):
    if v >= 10:
        raise ConfigError(f"{where} must be < 10 (a hook), got {v}")


@dataclass(frozen=True, kw_only=True)
class _Inner:
    a: float = option(1.0, lo=0.0, lo_open=True, why="a reason")
    where: str = where_field("inner")

    def __post_init__(self):
        check_options(self)


def _ordered(o, name):
    if o.lo_speed > o.hi_speed:
        raise ConfigError(f"{name('lo_speed')} must be <= hi_speed = {o.hi_speed}, got {o.lo_speed}")


@dataclass(frozen=True, kw_only=True)
class _All:
    req: tuple = option(kind="names", what="parameter names", split=True, nonempty=True)
    n: int = option(3, lo=1, check=_below_ten)
    on: bool = option(True)
    mode: str = option("a", choices=("a", "b"))
    body: str | None = option(None, kind="text", what="a body name", nonempty=True, none=True)
    inputs: str | tuple = option("all", kind="names", words=("all",), what="input names", unique=True)
    band: tuple = option((0.1, 0.2), items=2, lo=0.0, lo_open=True, increasing=True, what="0 < low < high")
    inner: _Inner = option(_Inner(), table=_Inner, what="a table of inner options")
    noise: dict | None = option(None, lo=0.0, unit="N", by_name=True, none=True, words=("auto",), what="deviations")
    bounds: dict | None = option(None, items=2, finite=False, increasing=True, by_name=True, none=True,
                                 what="(lower, upper)")
    lo_speed: float = option(0.0, unit="rad/s")
    hi_speed: float = option(1.0, unit="rad/s")
    where: str = where_field("all")

    def __post_init__(self):
        check_options(self, cross=_ordered)


@pytest.mark.parametrize("kw, match", [
    ({"req": []}, r"^all\.req must be a non-empty list of parameter names, got \[\]$"),
    ({"n": 0}, r"^all\.n must be an integer >= 1, got 0$"),
    ({"n": 12}, r"^all\.n must be < 10 \(a hook\), got 12$"),
    ({"on": 1}, r"^all\.on must be true or false, got 1$"),
    ({"mode": "c"}, r"^all\.mode must be one of a, b, got 'c'$"),
    ({"body": ""}, r"^all\.body must be a body name, got ''$"),
    ({"inputs": "some"}, r"^all\.inputs must be one of all or a list of input names, got 'some'$"),
    ({"inputs": ["x", "x"]}, r"^all\.inputs lists 'x' twice"),
    ({"band": (0.2, 0.1)}, r"^all\.band must be 0 < low < high, got \(0\.2, 0\.1\)$"),
    ({"band": 0.2}, r"^all\.band must be 0 < low < high, got 0\.2$"),
    ({"band": (0.0, 0.1)}, r"^all\.band must be 0 < low < high, got \(0\.0, 0\.1\)$"),
    ({"inner": 3}, r"^all\.inner must be a table of inner options, got int$"),
    ({"inner": {"a": 0}}, r"^all\.inner\.a must be > 0 \(a reason\), got 0$"),
    ({"inner": {"b": 1}}, r"^all\.inner\.b: unknown key; expected one of a$"),
    ({"noise": {"x": -1.0}}, r"^all\.noise\.x must be >= 0 N, got -1\.0$"),
    ({"noise": "loud"}, r"^all\.noise must be one of auto or a table of deviations, got 'loud'$"),
    ({"bounds": {"k": (1.0, float("nan"))}}, r"^all\.bounds\.k must be \(lower, upper\), got \(1\.0, nan\)$"),
    ({"lo_speed": 2.0}, r"^all\.lo_speed must be <= hi_speed = 1\.0, got 2\.0$"),
    ({"where": 3}, r"^all\.where must be the table's name, got 3$"),
])
def test_option_declares_each_kind_of_check(kw, match):
    with pytest.raises(ConfigError, match=match):
        _All(**{"req": ("k",), **kw})


def test_option_stores_what_it_checked_and_the_table_name():
    o = _All(req="k1, k2", band=[0.1, 0.3], inner={"a": 2}, noise={"x": 1}, bounds={"k": (0, float("inf"))},
             inputs=["u"])
    assert o.req == ("k1", "k2") and o.band == (0.1, 0.3) and o.inputs == ("u",)
    assert o.inner == _Inner(a=2.0, where="all.inner") and o.noise == {"x": 1.0} and o.bounds == {"k": (0.0, math.inf)}
    assert isinstance(o.inner.a, float) and o.where == "all" and _All(req=("k",), noise="auto").noise == "auto"
    # read from a table: the fields, the nested table and the where field all carry the table's name
    r = options_from_mapping(_All, {"req": ["k"], "inner": {"a": 3.0}}, "s.toml: x")
    assert r.where == "s.toml: x" and r.inner.where == "s.toml: x.inner"
    with pytest.raises(ConfigError, match=r"^s\.toml: x\.inner\.a must be > 0 \(a reason\), got -1$"):
        options_from_mapping(_All, {"req": ["k"], "inner": {"a": -1}}, "s.toml: x")
    with pytest.raises(ConfigError, match=r"^s\.toml: x\.where: unknown key"):     # the table's name is not a key
        options_from_mapping(_All, {"req": ["k"], "where": "y"}, "s.toml: x")
    with pytest.raises(TypeError, match="missing 1 required keyword-only argument: 'req'"):
        _All()


def _options_classes():
    """Every class named ``*Options`` in models/, estimators/ and mitigate/ (found in the source, so a
    new one is checked too), plus the NMPC's nested weights."""
    import ast
    import importlib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = []
    for pkg in ("models", "estimators", "mitigate"):
        for path in sorted((root / pkg).rglob("*.py")):
            names = [n.name for n in ast.parse(path.read_text()).body
                     if isinstance(n, ast.ClassDef) and n.name.endswith("Options")]
            if names:
                mod = importlib.import_module(".".join(path.relative_to(root).with_suffix("").parts))
                out += [getattr(mod, n) for n in names]
    from mitigate.controllers.nmpc.options import NMPCWeights
    return out + [NMPCWeights]


def test_every_options_class_declares_its_fields_with_option():
    """Issue 25 item 5: one option style.  Every field of every options class is declared with
    option() (or is its where_field), every class is frozen and keyword-only, and none has a
    from_mapping of its own."""
    import dataclasses

    classes = _options_classes()
    assert {"NMPCOptions", "IdentifyOptions", "SimOptions", "MetricOptions", "SweepOptions"} <= {c.__name__ for c in classes}
    for cls in classes:
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen, cls.__name__
        assert all(f.kw_only for f in dataclasses.fields(cls)), cls.__name__
        undeclared = [f.name for f in dataclasses.fields(cls) if "check" not in f.metadata and "where" not in f.metadata]
        assert not undeclared, f"{cls.__name__}: {undeclared} not declared with option()"
        own = getattr(cls, "from_mapping", None)
        assert own is None or own.__func__ is options_from_mapping, f"{cls.__name__} has its own from_mapping"


def test_a_number_option_with_a_unit_takes_a_quantity_as_files_do():
    """An option declared with an SI unit takes "<number> <unit>" and converts it (as rig and scenario
    files take quantities); a quantity of another dimension is one line naming the field."""
    from mitigate.controllers.nmpc import NMPCOptions
    o = NMPCOptions.from_mapping({"force_window": "500 ms", "force_filter": "2 s", "eps": "0.5 rpm", "dt": "50 ms"}, "c")
    assert (o.force_window, o.force_filter, o.dt) == (0.5, 2.0, 0.05) and o.eps == pytest.approx(0.5 * 2 * math.pi / 60)
    assert NMPCOptions.from_mapping({"force_window": 2.5}, "c").force_window == 2.5
    with pytest.raises(ConfigError, match=r"^c\.force_window must be a number in s or a quantity that converts to s, "
                                          r"got '2 N'$"):
        NMPCOptions.from_mapping({"force_window": "2 N"}, "c")
    with pytest.raises(ConfigError, match=r"^c\.force_window must be >= 0 s, got -1\.0$"):
        NMPCOptions.from_mapping({"force_window": "-1 s"}, "c")
