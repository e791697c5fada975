"""Sizes that cannot run are refused up front: one line naming the field and the limit, exit 2, nothing written.

Before, ``duration = 1e9`` ended in "internal error: MemoryError" and an NMPC with
``horizon = 100000`` spent minutes building its OCP.
"""

from pathlib import Path

import pytest

import mitigate.cli as cli
import mitigate.scenario as scenario_mod
import mitigate.scenario_fields as scenario_fields
from mitigate.scenario import BYTES_PER_SAMPLE, MAX_SAMPLES
from models.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "scenarios" / "stick_slip_30rpm.toml"


def _nmpc():
    import mitigate.controllers.nmpc as nmpc
    return nmpc


def main(argv):
    return cli.main(argv)


def _n_controllers() -> int:
    return len(scenario_mod.load_scenario(SHIPPED).controllers)


def _copy(tmp_path, *edits) -> Path:
    """The shipped main-job scenario, edited, in tmp_path."""
    text = SHIPPED.read_text()
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    p = tmp_path / "scenario.toml"
    p.write_text(text)
    return p


def _refused(tmp_path, capsys, scenario: Path, command=("run",)) -> str:
    out = tmp_path / "out"
    code = main([*command, str(scenario), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err and "internal error" not in err
    assert not out.exists()
    return err


def test_duration_1e9_is_refused_naming_duration_and_dt(tmp_path, capsys):
    err = _refused(tmp_path, capsys, _copy(tmp_path, ("duration = 60.0", "duration = 1e9")))
    assert "scenario.duration / scenario.dt = 1e+09 s / 0.01 s = 100,000,000,000 samples" in err
    assert f"the limit is {MAX_SAMPLES:,} samples" in err


def test_simulate_refuses_it_too(tmp_path, capsys):
    err = _refused(tmp_path, capsys, _copy(tmp_path, ("duration = 60.0", "duration = 1e9")), ("simulate",))
    assert "scenario.duration / scenario.dt" in err and f"the limit is {MAX_SAMPLES:,} samples" in err


def test_a_tiny_dt_counts_like_a_long_duration(tmp_path, capsys):
    err = _refused(tmp_path, capsys, _copy(tmp_path, ("dt = 0.01", "dt = 1e-300")))
    assert "= 60 s / 1e-300 s = 6e+301 samples; the limit is" in err


def test_more_samples_than_memory_holds_is_refused(tmp_path, capsys, monkeypatch):
    """Under the sample limit, but the controller runs would need more memory than the machine has."""
    # the size check reads the machine's memory where it lives (mitigate.scenario_fields)
    monkeypatch.setattr(scenario_fields, "memory_bytes", lambda: 2**30)      # a 1 GiB machine
    err = _refused(tmp_path, capsys, _copy(tmp_path, ("duration = 60.0", "duration = 20000.0")))
    n = _n_controllers()
    fit = 2**30 // (n * BYTES_PER_SAMPLE)
    need = 2_000_000 * n * BYTES_PER_SAMPLE / 2**30
    assert "scenario.duration / scenario.dt = 20000 s / 0.01 s = 2,000,000 samples" in err
    assert f"the limit is {fit:,} samples here: {n} controller run(s) need about {need:.1f} GiB" in err
    assert "this machine has 1.0 GiB of memory" in err


def test_the_shipped_scenario_is_within_both_limits(tmp_path):
    sc = scenario_mod.load_scenario(SHIPPED)
    n = len(sc.controllers)
    assert round(sc.duration / sc.dt) == 6000 and n >= 4
    have = scenario_mod.memory_bytes()
    if have is None:
        pytest.skip("this machine's memory is unknown (no sysconf, no cgroup limit): the memory limit is not checked")
    assert have > 100 * 6000 * n * BYTES_PER_SAMPLE


def test_nmpc_horizon_100000_is_refused(tmp_path, capsys):
    MAX_HORIZON = _nmpc().MAX_HORIZON
    p = _copy(tmp_path, ('name = "NMPC"\nkind = "nmpc"', 'name = "NMPC"\nkind = "nmpc"\nhorizon = 100000'))
    err = _refused(tmp_path, capsys, p)
    i = [c.kind for c in scenario_mod.load_scenario(SHIPPED).controllers].index("nmpc")
    assert f"scenario.toml: controller {i + 1} 'NMPC'.horizon must be <= {MAX_HORIZON}" in err and "got 100000" in err


def test_nmpc_horizon_limit_in_the_options():
    nmpc = _nmpc()
    MAX_HORIZON, NMPCOptions = nmpc.MAX_HORIZON, nmpc.NMPCOptions
    with pytest.raises(ConfigError, match=rf"^nmpc\.horizon must be <= {MAX_HORIZON} .*got {MAX_HORIZON + 1}$"):
        NMPCOptions(horizon=MAX_HORIZON + 1)
    assert NMPCOptions(horizon=MAX_HORIZON).horizon == MAX_HORIZON
