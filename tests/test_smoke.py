"""Smoke tests of the package layout, the public API and the CLI entry point."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_public_api_resolves():
    import estimators
    import mitigate
    import models
    for pkg in (mitigate, models, estimators):
        missing = [n for n in pkg.__all__ if not hasattr(pkg, n)]
        assert not missing, (pkg.__name__, missing)
    assert set(mitigate.CONTROLLER_KINDS) >= {"pi", "brake", "supervisor", "softspeed", "ztorque", "doskil", "nmpc"}


@pytest.mark.slow
def test_cli_unknown_command_is_one_line_exit_2():
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "bogus"], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


@pytest.mark.slow
def test_cli_help_exits_zero():
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "--help"], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0
    assert "mitigate" in r.stdout
    for cmd in ("simulate", "modal", "identify", "estimate", "run", "sweep", "benchmark"):
        assert cmd in r.stdout
