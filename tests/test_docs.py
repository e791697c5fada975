"""The documentation site: it builds with no warning, and what its pages show runs.

Conventions of the pages in ``docs/`` (also stated in ``docs/index.md``):

- every fenced ```python block runs, in order, one namespace per page, with a temporary working
  folder holding links to the repository's ``scenarios/``, ``tests/`` and ``models/`` (so
  ``"scenarios/stick_slip_30rpm.toml"`` reads as in the README). The quick pages share one fresh
  interpreter (each its own namespace); a slow page runs in its own;
  a block preceded by the line ``<!-- norun -->`` is an excerpt and is not run;
- a page holding ``<!-- docs-test: slow -->`` has its blocks' test marked slow;
- every ```toml block not marked ``<!-- norun -->`` parses; one with a ``[rig]`` table is built
  by :func:`models.load_rig`, one with a ``[scenario]`` table by :func:`mitigate.load_scenario`;
- every ``mitigate ...`` line of a ```bash block parses with the CLI's own parser.

The README's length is checked here too: at most 1,500 words (``wc -w``), the rest is in docs/.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
NORUN = "<!-- norun -->"
SLOW = "<!-- docs-test: slow -->"
README_WORDS = 1500
# ``` or ~~~ fences; the info string's first word is the language
FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>```|~~~)[ \t]*(?P<lang>[\w+-]*)[^\n]*\n(?P<body>.*?)^(?P=indent)(?P=fence)[ \t]*$",
                   flags=re.M | re.S)


def pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.md") if "tools" not in p.relative_to(DOCS).parts)


def blocks(path: Path, lang: str) -> list[tuple[int, str]]:
    """(line, code) of each fenced block of ``lang`` in ``path`` that is not marked ``<!-- norun -->``.

    An indented block (inside a list item) is dedented by its fence's indent.
    """
    text = path.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        if m.group("lang") != lang:
            continue
        before = text[:m.start()].rstrip().splitlines()
        if before and before[-1].strip() == NORUN:
            continue
        indent = len(m.group("indent"))
        code = "".join(ln[indent:] if ln[:indent].strip() == "" else ln for ln in m.group("body").splitlines(True))
        out.append((text.count("\n", 0, m.start()) + 2, code))
    return out


def _page_id(p: Path) -> str:
    return p.relative_to(DOCS).as_posix()


def _python_pages():
    params = []
    for p in pages():
        if blocks(p, "python"):
            marks = [pytest.mark.slow] if SLOW in p.read_text(encoding="utf-8") else []
            params.append(pytest.param(p, id=_page_id(p), marks=marks))
    return params


# --- the README --------------------------------------------------------------------------

def test_readme_is_at_most_1500_words():
    words = len((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert words <= README_WORDS, f"README.md has {words} words (wc -w); at most {README_WORDS}: move detail to docs/"


def test_readme_links_resolve():
    """Every relative link of the README (to docs/ pages, the figure, results) names a file that exists."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = [t.split("#", 1)[0] for t in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in t]
    assert targets, "the README links nothing"
    missing = [t for t in targets if t and not (ROOT / t).exists()]
    assert not missing, f"README.md links files that do not exist: {missing}"


# --- the pages' code ---------------------------------------------------------------------

def test_the_conventions_find_blocks_and_skip_excerpts(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("text\n\n```python\nx = 1\n```\n\n<!-- norun -->\n```python\nraise SystemExit\n```\n\n"
                    "- item:\n\n    ```python\n    y = x + 1\n    ```\n")
    assert blocks(page, "python") == [(4, "x = 1\n"), (15, "y = x + 1\n")]


def _workdir(base: Path) -> Path:
    """A working folder for a page: links to the repository's scenarios/, tests/ and models/."""
    base.mkdir(parents=True, exist_ok=True)
    for name in ("scenarios", "tests", "models"):
        (base / name).symlink_to(ROOT / name, target_is_directory=True)
    return base


def _script(page: Path) -> str:
    return "\n".join(f"# --- {_page_id(page)}, block at line {line}\n{code}" for line, code in blocks(page, "python"))


# Runs each page's script in its own namespace and working folder, in ONE interpreter (the quick
# pages: an interpreter with casadi imported costs seconds, the pages' code much less); prints one
# JSON line {page: "ok" | traceback}.
DRIVER = """
import json, os, sys, traceback
out = {}
for page, script, cwd in json.load(open(sys.argv[1])):
    os.chdir(cwd)
    try:
        exec(compile(script, page, "exec"), {"__name__": "__main__"})
        out[page] = "ok"
    except BaseException:
        out[page] = traceback.format_exc()[-3000:]
print("RESULTS " + json.dumps(out))
"""


def _run_pages(todo: list[Path], tmp: Path) -> dict[str, str]:
    import json

    jobs = [(_page_id(p), _script(p), str(_workdir(tmp / p.stem))) for p in todo]
    (tmp / "jobs.json").write_text(json.dumps(jobs))
    (tmp / "driver.py").write_text(DRIVER)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    p = subprocess.run([sys.executable, str(tmp / "driver.py"), str(tmp / "jobs.json")], cwd=tmp, env=env,
                       capture_output=True, text=True, timeout=900)
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULTS ")]
    if not line:
        return {page: f"the interpreter died (exit {p.returncode}):\n{p.stderr[-3000:]}" for page, _, _ in jobs}
    return json.loads(line[-1][len("RESULTS "):])


@pytest.fixture(scope="module")
def quick_pages(tmp_path_factory) -> dict[str, str]:
    todo = [p for p in pages() if blocks(p, "python") and SLOW not in p.read_text(encoding="utf-8")]
    return _run_pages(todo, tmp_path_factory.mktemp("docs_pages"))


@pytest.mark.parametrize("page", _python_pages())
def test_python_blocks_run(page, request, tmp_path):
    """A page's Python blocks, joined in order, run as one script in their own namespace (the quick
    pages share one fresh interpreter; a slow page gets its own)."""
    if SLOW in page.read_text(encoding="utf-8"):
        result = _run_pages([page], tmp_path)[_page_id(page)]
    else:
        result = request.getfixturevalue("quick_pages")[_page_id(page)]
    assert result == "ok", f"{_page_id(page)}: its Python blocks failed:\n{result}"


def test_the_plugin_page_quotes_the_tested_example():
    """docs/plugins.md shows tests/plugins/my_controller.py's code (run by tests/test_user_controller.py)."""
    shown = blocks(DOCS / "plugins.md", "python")[0][1]
    example = (ROOT / "tests" / "plugins" / "my_controller.py").read_text(encoding="utf-8")
    assert "class HighPassTorque(Controller):" in shown
    assert shown.strip() in example, "docs/plugins.md's first block is no longer the code of tests/plugins/my_controller.py"


def test_toml_blocks_parse_and_whole_files_load(tmp_path):
    from mitigate import load_scenario
    from models import load_rig

    checked = {"rig": 0, "scenario": 0, "fragment": 0}
    for page in pages():
        for line, code in blocks(page, "toml"):
            where = f"{_page_id(page)}:{line}"
            try:
                data = tomllib.loads(code)
            except tomllib.TOMLDecodeError as exc:
                pytest.fail(f"{where}: not valid TOML ({exc}); mark an excerpt with {NORUN}")
            kind = "rig" if "rig" in data else "scenario" if "scenario" in data else "fragment"
            if kind != "fragment":
                path = tmp_path / f"{page.stem}_{line}.toml"
                path.write_text(code)
                (load_rig if kind == "rig" else load_scenario)(path)
            checked[kind] += 1
    # the conventions cannot pass vacuously: the pages hold whole files of both kinds
    assert checked["rig"] >= 1 and checked["scenario"] >= 2, checked


def _mitigate_lines(code: str) -> list[str]:
    """The ``mitigate ...`` command lines of a bash block (continuations joined, comments cut)."""
    joined = re.sub(r"\\\n\s*", " ", code)
    out = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        for i, w in enumerate(words):             # also after "&&" (the README's command 1)
            if w == "mitigate" and (i == 0 or words[i - 1] == "&&"):
                end = words.index("&&", i) if "&&" in words[i:] else len(words)
                out.append(words[i + 1:end])
    return out


def test_bash_blocks_mitigate_lines_parse():
    from mitigate.cli import build_parser

    parser = build_parser()
    n = 0
    sources = [(p, _page_id(p)) for p in pages()] + [(ROOT / "README.md", "README.md")]
    for path, name in sources:
        for line, code in blocks(path, "bash"):
            for argv in _mitigate_lines(code):
                try:
                    args = parser.parse_args(argv)
                except SystemExit:
                    pytest.fail(f"{name}:{line}: `mitigate {' '.join(argv)}` does not parse (the CLI changed?)")
                assert getattr(args, "func", None), f"{name}:{line}: `mitigate {' '.join(argv)}` names no command"
                n += 1
    assert n >= 20, n


# --- the site ----------------------------------------------------------------------------

def test_numpydoc_entries_become_descriptions_and_types_stay():
    """docs/tools/griffe_numpydoc.py: ``name : what it is`` is a description; ``name : int`` a type."""
    sys.path.insert(0, str(DOCS / "tools"))
    try:
        from griffe_numpydoc import rewrite
    finally:
        sys.path.remove(str(DOCS / "tools"))
    doc = ("Summary.\n\n    Parameters\n    ----------\n    log : a Log holding\n        the inputs\n"
           "    n : int | None\n        how many\n\n    Raises\n    ------\n    ConfigError : a bad spec\n\n"
           "    Notes\n    -----\n    x : y stays prose here\n")
    assert rewrite(doc) == ("Summary.\n\n    Parameters\n    ----------\n    log\n        a Log holding\n        the inputs\n"
                            "    n : int | None\n        how many\n\n    Raises\n    ------\n    ConfigError\n        a bad spec"
                            "\n\n    Notes\n    -----\n    x : y stays prose here")


@pytest.mark.slow
def test_site_builds_strict_with_no_warning(tmp_path):
    """``mkdocs build --strict`` into a temporary folder: any warning (a broken link or anchor, a
    docstring griffe cannot read, a page missing from the nav's files) fails it."""
    if shutil.which("mkdocs") is None and subprocess.run([sys.executable, "-c", "import mkdocs"]).returncode:
        pytest.fail("mkdocs is not installed: pip install -e '.[test]'")
    site = tmp_path / "site"
    p = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    warnings = [ln for ln in (p.stdout + p.stderr).splitlines() if ln.startswith(("WARNING", "ERROR"))]
    assert p.returncode == 0 and not warnings, "mkdocs build --strict:\n" + "\n".join(warnings or [p.stderr[-3000:]])
    # the generated parts are there: the CLI's help of every command, the API from the docstrings
    from mitigate.cli import COMMANDS
    cli = (site / "cli" / "index.html").read_text(encoding="utf-8")
    assert all(f"usage: mitigate {c}" in cli for c in COMMANDS), "the CLI page lacks a command's help"
    api = (site / "api" / "mitigate" / "index.html").read_text(encoding="utf-8")
    assert 'id="mitigate.run"' in api and 'id="mitigate.make_scenario"' in api
    # a results file a page links is published, not a broken link
    assert (site / "repo" / "benchmarks" / "results" / "nmpc" / "index.html").is_file()
