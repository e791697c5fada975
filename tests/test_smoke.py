"""Smoke tests of the package layout, the public API and the CLI entry point."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _identify_imports() -> bool:
    try:
        importlib.import_module("mitigate.commands.identify")
        importlib.import_module("mitigate.commands.estimate")
        return True
    except Exception:  # noqa: BLE001 - another branch owns them; until it lands the full CLI cannot build
        return False


def test_the_public_api_resolves():
    import mitigate
    import models
    for pkg in (mitigate, models):
        missing = [n for n in pkg.__all__ if not hasattr(pkg, n)]
        assert not missing, (pkg.__name__, missing)
    assert set(mitigate.CONTROLLER_KINDS) >= {"pi", "brake", "supervisor", "softspeed", "ztorque", "doskil", "nmpc"}


def test_cli_help_of_the_migrated_commands():
    code = ("import sys; import mitigate.cli as cli; cli.COMMANDS = ('simulate', 'modal', 'run', 'sweep', 'benchmark'); "
            "sys.exit(cli.main(sys.argv[1:]))")
    r = subprocess.run([sys.executable, "-c", code, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    for cmd in ("simulate", "modal", "run", "sweep", "benchmark"):
        assert cmd in r.stdout
    r = subprocess.run([sys.executable, "-c", code, "bogus"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


@pytest.mark.skipif(not _identify_imports(), reason="mitigate.commands.identify/estimate do not import yet")
def test_cli_help_exits_zero():
    r = subprocess.run([sys.executable, "-m", "mitigate.cli", "--help"], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0
    assert "mitigate" in r.stdout
    for cmd in ("simulate", "modal", "identify", "estimate", "run", "sweep", "benchmark"):
        assert cmd in r.stdout
