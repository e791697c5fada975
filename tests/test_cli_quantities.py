"""CLI quantities accept units as files do (issue 28, item 5): ``--omega "5 rpm"``.

Every flag that takes a physical quantity goes through one argparse type,
:func:`mitigate.cliutil.quantity` (built on :mod:`models.units`): a number in SI or a value with its
unit; a bad one is one line naming the flag, what was expected and what came, exit 2.
"""

from __future__ import annotations

import argparse
import json
import math
import re

import pytest

from mitigate.cli import build_parser, main
from mitigate.cliutil import quantity
from mitigate.sweep import parse_axis
from models.errors import ConfigError
from models.units import convert


@pytest.mark.parametrize("kind, text, si", [
    ("speed", "3.5", 3.5), ("speed", "30 rpm", math.pi), ("speed", "0.5 Hz", math.pi), ("speed", "180 deg/s", math.pi),
    ("force", "0.8 kN", 800.0), ("force", "-2", -2.0), ("time", "250 ms", 0.25), ("time", "2 min", 120.0),
    ("rate", "0.5 Hz", 0.5), ("torque", "2 kN m", 2000.0), ("speed", "1e-3", 1e-3),
])
def test_a_number_is_si_and_a_unit_converts(kind, text, si):
    assert quantity(kind)(text) == pytest.approx(si, rel=1e-12)


@pytest.mark.parametrize("text, why", [
    ("5 kN", "unit [kN] does not convert to a speed"), ("5 furlong", "unknown symbol 'furlong'"),
    ("fast", "got 'fast'"), ("1e400", "got '1e400'"), ("-1 rpm", "(-0.10472 rad/s)"), ("0", "got '0'"),
])
def test_a_bad_value_says_what_was_expected_and_what_came(text, why):
    with pytest.raises(argparse.ArgumentTypeError) as exc:
        quantity("speed", lo=0.0, lo_open=True)(text)
    msg = str(exc.value)
    assert msg.startswith('expected a speed > 0 rad/s (a number in rad/s, or with its unit, e.g. "30 rpm"), got ')
    assert why in msg


def test_modal_takes_rpm_and_kn_and_gives_the_same_modes_as_si(capsys):
    """The user's --omega "5 rpm" (refused before) and the same point in SI: identical linearisations."""
    assert main(["modal", "--variant", "closed", "--omega", "5 rpm", "--load", "0.025 kN", "--json"]) == 0
    with_units = json.loads(capsys.readouterr().out)
    assert main(["modal", "--variant", "closed", "--omega", repr(5 * 2 * math.pi / 60), "--load", "25", "--json"]) == 0
    si = json.loads(capsys.readouterr().out)
    a, b = with_units["variants"]["closed"], si["variants"]["closed"]
    assert a["max_real"] == pytest.approx(b["max_real"], rel=1e-9) and a["freq_hz"] == pytest.approx(b["freq_hz"])


@pytest.mark.parametrize("argv, head", [
    (["modal", "--omega", "5 kN"], "mitigate modal: error: argument --omega: expected a speed"),
    (["modal", "--load", "-3 N"], "mitigate modal: error: argument --load: expected a force >= 0 N"),
    (["identify", "x.csv", "--model", "rig3", "--free", "k1", "--eps", "fast"],
     "mitigate identify: error: argument --eps: expected a speed (a number in rad/s"),
    (["identify", "x.csv", "--model", "rig3", "--free", "k1", "--input-cutoff", "n1=5 N"],
     "mitigate identify: error: --input-cutoff n1: expected a rate (a number in 1/s"),
    (["identify", "x.csv", "--model", "rig3", "--free", "k1", "--input-noise", "n1=0.2 N m"],
     "mitigate identify: error: --input-noise n1: expected a force > 0 N"),
    (["sweep", "scenarios/sweep_rig3.toml", "--duration", "1 kg"], "mitigate sweep: error: argument --duration: "),
    (["sweep", "scenarios/sweep_rig3.toml", "--vary", "omega_ref=10 kN:60 rpm:3"],
     "mitigate sweep: error: --vary omega_ref: unit [kN] does not convert to [rad/s]"),
    (["benchmark", "x.toml", "--scheduler-timeout", "soon"], "mitigate benchmark: error: argument --scheduler-timeout"),
    (["export", "x.toml", "--controller", "N", "--out", "o", "--reference", "-1 s"],
     "mitigate export: error: argument --reference: expected a time >= 0 s"),
])
def test_bad_quantities_are_one_line_naming_the_flag_exit_2(argv, head, capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    with pytest.raises(SystemExit) as ex:
        raise SystemExit(main(argv))
    assert ex.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(head), err
    assert "Traceback" not in err


def test_sweep_axes_take_units_of_their_input_or_parameter():
    a = parse_axis("omega_ref=10 rpm:60 rpm:6", {"omega_ref": "rad/s"})
    assert (a.start, a.stop, a.count) == pytest.approx((10 * math.pi / 30, 2 * math.pi, 6))
    assert parse_axis("n1=0.005 kN:40:8", {"n1": "N"}).start == pytest.approx(5.0)
    assert parse_axis("n1=5:40:8").values.tolist()[0] == 5.0          # numbers as before
    with pytest.raises(ConfigError, match="'K_scale' is not an input or parameter whose unit is known"):
        parse_axis("K_scale=1 N:2 N:2", {"n1": "N"})
    assert convert(30, "rpm", "rad/s") == pytest.approx(math.pi) and convert(1, "Hz", "rad/s") == pytest.approx(2 * math.pi)


def test_no_quantity_flag_is_left_to_float():
    """Every flag's ``type`` is the quantity helper, an integer or a dimensionless float; a float flag
    is one of the listed dimensionless ones (a fraction, a scale factor)."""
    dimensionless = {("identify", "--holdout"), ("identify", "--noise-scale")}
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    seen_quantity = set()
    for name, p in sub.choices.items():
        for act in p._actions:
            flag = act.option_strings[-1] if act.option_strings else act.dest
            if act.type is float:
                assert (name, flag) in dimensionless, f"mitigate {name} {flag} takes a bare float"
            elif act.type is not None and getattr(act.type, "__module__", "") == "mitigate.cliutil":
                seen_quantity.add((name, flag))
    assert {("modal", "--omega"), ("modal", "--load"), ("identify", "--eps"), ("sweep", "--duration"),
            ("sweep", "--settle"), ("sweep", "--scheduler-timeout"), ("benchmark", "--scheduler-timeout"),
            ("export", "--reference")} <= seen_quantity
    assert all(re.fullmatch(r"--[a-z-]+", f) for _n, f in seen_quantity)
