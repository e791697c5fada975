"""The README's "From Python" code runs: its ```python blocks, in order, in one namespace.

Editing the README's examples without keeping them runnable fails here (issue: a Python API as
good as the CLI, documented with code that cannot rot)."""

import re
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
    out = capsys.readouterr().out
    assert "Status" not in out or "ok" in out
    assert (tmp_path / "demo_nmpc.png").stat().st_size > 10_000
    # what the blocks compute is physically what the README says
    assert 0.10 < ns["np"].mean(ns["sim"].state("omega_R1")[1000:] == 0.0) < 0.25
    assert ns["fit"].success
    assert ns["result"].run("NMPC").metrics["sss_final"] < 0.1 < ns["result"].run("pi").metrics["sss_final"]
