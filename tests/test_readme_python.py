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
def test_from_python_blocks_run_as_a_script_file_without_a_main_guard(tmp_path):
    """The blocks, in order, joined into one script FILE with no ``if __name__ == "__main__":`` guard,
    run in a fresh interpreter (``run()`` does not let spawned workers run the script's top level
    again: mitigate.workers), and compute what the README says they do."""
    script = tmp_path / "readme_blocks.py"
    script.write_text("\n".join(_blocks()) + "\nimport json as _json\n"
                      "print('DONE', result.status.value, [r.status.value for r in result.runs])\n"
                      "print('CHECK', _json.dumps({'sim': sim.status.value, 'stuck': float(np.mean(sim.state('omega_R1')[1000:] "
                      "== 0.0)), 'fit': bool(fit.success), 'nmpc': result.run('NMPC').metrics['sss_final'], "
                      "'pi': result.run('pi').metrics['sss_final']}))\n")
    root = str(README.parent)
    env = {"PYTHONPATH": root, "PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    import os
    env["HOME"] = os.environ.get("HOME", str(tmp_path))       # the compiled-code cache
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "DONE ok ['ok', 'ok']" in p.stdout, p.stdout[-2000:]
    assert (tmp_path / "demo_nmpc.png").stat().st_size > 10_000
    # what the blocks compute is physically what the README says
    import json
    got = json.loads(p.stdout.split("CHECK ", 1)[1].splitlines()[0])
    assert got["sim"] == "ok" and 0.10 < got["stuck"] < 0.25 and got["fit"]
    assert got["nmpc"] < 0.1 < got["pi"]
