"""``control.start`` or ``dt`` beyond the run: one line, exit 2, nothing written, on every path
(issue 28, item 6).  ``mitigate run`` is covered in test_fuzz_faults.py; these are the sweep, the
benchmark and the tuner.  A closed-loop sweep's runs last ``sweep.duration`` (``--duration``), not the
scenario's: before, ``--duration 1`` with ``control.start = 3`` swept a controller that never acted,
wrote its maps and exited 0."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import mitigate.cli as cli
from mitigate.sweep import sweep
from models.errors import ConfigError
from test_fuzz_faults import SUITE, tiny

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def ws(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PYTHONPATH", str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    (tmp_path / "tiny.toml").write_text(tiny(duration=4.0, start=3.0))
    (tmp_path / "late.toml").write_text(tiny(name="late", start=5.0))
    (tmp_path / "short.toml").write_text(tiny(name="short", duration=0.004, start=0.0))
    for name in ("late", "short"):
        (tmp_path / f"suite_{name}.toml").write_text(SUITE.format(extra="").replace('"tiny.toml"', f'"{name}.toml"'))
    return tmp_path


def refused(capsys, argv, *words):
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for w in words:
        assert w in err, err
    return err


def test_a_closed_loop_sweep_that_ends_before_the_switch_on_is_refused(ws, capsys):
    refused(capsys, ["sweep", "tiny.toml", "--controller", "PI only", "--vary", "n1=5:40:2", "--duration", "1",
                     "--no-stability", "--out", "o"],
            "sweep.duration must be > control.start = 3 s for a closed-loop sweep", "got 1 s")
    assert not (ws / "o").exists()
    with pytest.raises(ConfigError, match="control.start = 3 s"):
        sweep("tiny.toml", ["n1=5:40:2"], out="o2", controller="PI only", duration=1.0)
    assert not (ws / "o2").exists()
    refused(capsys, ["sweep", "tiny.toml", "--controller", "nope", "--vary", "n1=5:40:2", "--out", "o"],
            "--controller must be one of the scenario's [[controllers]] names ['PI only'], got 'nope'")


@pytest.mark.parametrize("suite, words", [
    ("suite_late.toml", ("late.toml: control.start must be < scenario.duration = 2 s", "got 5 s")),
    ("suite_short.toml", ("short.toml: scenario.dt must be <= scenario.duration = 0.004 s", "got 0.01 s")),
])
def test_the_benchmark_refuses_such_a_scenario_before_writing(ws, capsys, suite, words):
    refused(capsys, ["benchmark", suite, "--quick", "--out", "o"], *words)
    assert not (ws / "o").exists()


def test_the_tuner_refuses_it_too(ws, capsys):
    refused(capsys, ["tune", "late.toml", "--controller", "PI only", "--budget", "1"],
            "control.start must be < scenario.duration = 2 s")
    assert sorted(p.name for p in ws.iterdir()) == sorted(["tiny.toml", "late.toml", "short.toml", "suite_late.toml",
                                                          "suite_short.toml"])
