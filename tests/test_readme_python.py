"""The README's "From Python" code runs: its ```python blocks, in order, in one namespace.

Editing the README's examples without keeping them runnable fails here (issue: a Python API as
good as the CLI, documented with code that cannot rot)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def _blocks() -> list[str]:
    text = README.read_text()
    start = text.index("## From Python")
    end = text.index("\n## ", start + 3)
    return re.findall(r"```python\n(.*?)```", text[start:end], flags=re.S)


def test_the_readme_has_from_python_blocks():
    blocks = _blocks()
    assert len(blocks) >= 3
    joined = "\n".join(blocks)
    for needed in ("simulate(", "modes(", "identify(", "run(", "plot_run("):
        assert needed in joined, needed


@pytest.mark.slow
def test_from_python_blocks_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for i, code in enumerate(_blocks()):
        exec(compile(code, f"README.md From Python block {i + 1}", "exec"), ns)   # noqa: S102 - our own README
    from models import Status
    assert ns["sim"].status is Status.OK and ns["result"].status is Status.OK
    assert all(r.status is Status.OK for r in ns["result"].runs)
    assert (tmp_path / "demo_nmpc.png").stat().st_size > 10_000
    # what the blocks compute is physically what the README says
    assert 0.10 < ns["np"].mean(ns["sim"].state("omega_R1")[1000:] == 0.0) < 0.25
    assert ns["fit"].success
    assert ns["result"].run("NMPC").metrics["sss_final"] < 0.1 < ns["result"].run("pi").metrics["sss_final"]


@pytest.mark.slow
def test_from_python_blocks_run_as_a_script_file_without_a_main_guard(tmp_path):
    """The blocks, joined into one script FILE with no ``if __name__ == "__main__":`` guard, run in a
    fresh interpreter: ``run()`` does not let spawned workers run the script's top level again
    (mitigate.workers); and read from stdin (``python - < script.py``)."""
    script = tmp_path / "readme_blocks.py"
    script.write_text("\n".join(_blocks()) + "\nprint('DONE', result.status.value, [r.status.value for r in result.runs])\n")
    root = str(README.parent)
    env = {"PYTHONPATH": root, "PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    import os
    env["HOME"] = os.environ.get("HOME", str(tmp_path))       # the compiled-code cache
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "DONE ok ['ok', 'ok']" in p.stdout, p.stdout[-2000:]
    assert (tmp_path / "demo_nmpc.png").stat().st_size > 10_000
