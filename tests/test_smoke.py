"""Smoke test of the package layout and CLI entry point."""

import subprocess
import sys


def test_cli_help_exits_zero():
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "--help"], capture_output=True, text=True)
    assert r.returncode == 0
    assert "mitigate" in r.stdout
