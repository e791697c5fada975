"""README.md's two commands and the ones .ci/run runs are the same text.

README.md, section "## The two commands", gives two ```bash blocks: command 1 (install and
run the main job) and command 2 (install the test extras and run the tests).  .ci/run runs
each of them on the line after a marker comment ``# --- README command N, verbatim ---``.
Editing one side without the other fails here.

Also run by .ci/run before anything is installed (standard library only):
``python3 tests/test_readme_commands.py`` exits 1 with one line per difference.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## The two commands"
MARKER = "# --- README command {n}, verbatim ---"


def readme_commands(text: str) -> list[str]:
    """The command of each ```bash block in the README's "## The two commands" section."""
    start = text.find("\n" + SECTION + "\n")
    if start < 0:
        raise ValueError(f"README.md has no section {SECTION!r}")
    body = text[start + len(SECTION) + 2:]
    nxt = re.search(r"^## ", body, flags=re.M)
    body = body[:nxt.start()] if nxt else body
    cmds = []
    for block in re.findall(r"^[ \t]*```bash[ \t]*\n(.*?)^[ \t]*```[ \t]*$", body, flags=re.M | re.S):
        lines = [ln.strip() for ln in block.splitlines() if ln.strip()]
        if len(lines) != 1:
            raise ValueError(f"README.md {SECTION!r}: each ```bash block must hold one command line, got {lines}")
        cmds.append(lines[0])
    if len(cmds) != 2:
        raise ValueError(f"README.md {SECTION!r}: expected 2 ```bash blocks, got {len(cmds)}")
    return cmds


def ci_commands(text: str) -> list[str]:
    """The line after each ``# --- README command N, verbatim ---`` marker of .ci/run (N = 1, 2)."""
    lines = [ln.strip() for ln in text.splitlines()]
    cmds = []
    for n in (1, 2):
        at = [i for i, ln in enumerate(lines) if ln == MARKER.format(n=n)]
        if len(at) != 1:
            raise ValueError(f".ci/run: expected the marker {MARKER.format(n=n)!r} once, got it {len(at)} times")
        rest = [ln for ln in lines[at[0] + 1:] if ln]
        if not rest:
            raise ValueError(f".ci/run: no command after {MARKER.format(n=n)!r}")
        cmds.append(rest[0])
    return cmds


def differences(readme: str, ci: str) -> list[str]:
    """One line per command that differs between README.md and .ci/run (empty: they agree)."""
    return [f"README command {n}: README.md has {r!r}, .ci/run runs {c!r}"
            for n, (r, c) in enumerate(zip(readme_commands(readme), ci_commands(ci)), start=1) if r != c]


def _texts() -> tuple[str, str]:
    return (ROOT / "README.md").read_text(encoding="utf-8"), (ROOT / ".ci" / "run").read_text(encoding="utf-8")


# --- tests -------------------------------------------------------------------------------

def test_readme_and_ci_run_the_same_two_commands():
    readme, ci = _texts()
    assert readme_commands(readme) == [
        "python -m pip install . && mitigate run scenarios/stick_slip_30rpm.toml --out out/",
        'python -m pip install -e ".[test]" && python -m pytest -q',
    ]
    assert differences(readme, ci) == []


def test_ci_run_keeps_pytest_and_fresh_environments():
    _, ci = _texts()
    assert "python -m pytest" in ci
    assert "set -euo pipefail" in ci
    assert ci.count("-m venv ") == 2     # one fresh virtual environment per command


def test_an_edit_on_one_side_only_is_caught():
    readme, ci = _texts()
    edited_readme = readme.replace("--out out/", "--out results/", 1)
    assert differences(edited_readme, ci) == [
        "README command 1: README.md has 'python -m pip install . && mitigate run scenarios/stick_slip_30rpm.toml "
        "--out results/', .ci/run runs 'python -m pip install . && mitigate run scenarios/stick_slip_30rpm.toml "
        "--out out/'"]
    edited_ci = ci.replace("python -m pytest -q", "python -m pytest -q -m 'not slow'", 1)
    diff = differences(readme, edited_ci)
    assert len(diff) == 1 and diff[0].startswith("README command 2:") and "not slow" in diff[0]


def test_a_readme_without_the_section_or_with_a_third_block_is_an_error():
    import pytest

    readme, _ = _texts()
    with pytest.raises(ValueError, match="no section"):
        readme_commands(readme.replace(SECTION, "## Two commands"))
    third = readme.replace(SECTION + "\n", SECTION + "\n\n```bash\nmake all\n```\n", 1)
    with pytest.raises(ValueError, match="expected 2 ```bash blocks, got 3"):
        readme_commands(third)


if __name__ == "__main__":
    try:
        problems = differences(*_texts())
    except ValueError as exc:
        problems = [str(exc)]
    for p in problems:
        print(f"{Path(sys.argv[0]).name}: {p}", file=sys.stderr)
    sys.exit(1 if problems else 0)
