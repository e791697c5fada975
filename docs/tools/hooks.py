"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks``).

Two jobs, so that the pages' sources read well on their own (in an editor, or on a code host)
and the site built from them has no broken link and no stale text:

1. **Files of the repository linked from a page.** A page links a measured result, a rig file or a
   scenario where it lives, relative to the page: ``[results](../benchmarks/results/nmpc.md)``.
   Such a target lies outside ``docs/``, which MkDocs does not publish; these hooks add it to the
   site under ``repo/`` (``repo/benchmarks/results/nmpc.md``, rendered as a page if it is
   Markdown, copied as it is otherwise) and rewrite the link to it. Markdown files added this way
   are scanned in turn, so their own links resolve too. A link to a file that does not exist is
   left as it is, and ``mkdocs build --strict`` reports it.
2. **The CLI reference.** In a page, ``<!-- mitigate-help: NAME -->`` becomes the ``--help`` text of
   ``mitigate NAME`` (``<!-- mitigate-help -->`` the top-level help), taken from the parsers in
   ``mitigate/commands/`` at build time. A command that ``mitigate.cli.COMMANDS`` has and no page
   marks is appended to the page holding ``<!-- mitigate-help-rest -->``, so every command is
   documented even before someone writes its prose.
"""

from __future__ import annotations

import logging
import os
import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.docs")     # under "mkdocs": a warning fails --strict

REPO_PREFIX = "repo"
# an inline Markdown link or image target: ](target) or ](target "title"), fragment allowed
LINK = re.compile(r"(\]\()([^)\s]+)((?:\s+\"[^\"]*\")?\))")
FENCE = re.compile(r"^([ \t]*)(```|~~~)")
# a marker alone on its line (one quoted in prose or code is left alone)
HELP = re.compile(r"^[ \t]*<!--\s*mitigate-help(?::\s*([\w-]+))?\s*-->[ \t]*$", flags=re.M)
HELP_REST = "<!-- mitigate-help-rest -->"
HELP_COLUMNS = "96"


def _root(config) -> Path:
    return Path(config["config_file_path"]).resolve().parent


def _outside_code(markdown: str):
    """(start, end) spans of ``markdown`` that are not inside fenced code blocks."""
    spans, pos, fence = [], 0, None
    offset = 0
    for line in markdown.splitlines(keepends=True):
        m = FENCE.match(line)
        if m and fence is None:
            spans.append((pos, offset))
            fence = m.group(2)
        elif m and line.strip().startswith(fence or "\0"):
            pos = offset + len(line)
            fence = None
        offset += len(line)
    if fence is None:
        spans.append((pos, offset))
    return spans


def _targets(markdown: str):
    """Relative link targets (path, without fragment) outside fenced code."""
    for a, b in _outside_code(markdown):
        for m in LINK.finditer(markdown, a, b):
            target = m.group(2).split("#", 1)[0]
            if target and "://" not in target and not target.startswith(("/", "mailto:", "#")):
                yield target


def _repo_path(page_src: str, target: str, docs_dir: Path, root: Path) -> str | None:
    """The repository path (posix, from the root) a page's link points to, if it leaves ``docs/``.

    ``page_src`` is the page's ``src_uri``; a page already under ``repo/`` stands at its
    repository path, so its relative links are resolved there.
    """
    docs_rel = docs_dir.relative_to(root).as_posix()
    if page_src.startswith(REPO_PREFIX + "/"):
        here = posixpath.dirname(page_src[len(REPO_PREFIX) + 1:])
    else:
        here = posixpath.join(docs_rel, posixpath.dirname(page_src))
    where = posixpath.normpath(posixpath.join(here, target))
    if where.startswith("../") or where == ".." or where == docs_rel or where.startswith(docs_rel + "/"):
        return None
    return where if (root / where).is_file() else None


def on_files(files, config):
    """Add every repository file that a page (or an added Markdown file) links to, under ``repo/``."""
    root, docs_dir = _root(config), Path(config["docs_dir"]).resolve()
    todo = [f for f in files.documentation_pages()]
    added: set[str] = set()
    while todo:
        f = todo.pop()
        text = Path(f.abs_src_path).read_text(encoding="utf-8")
        for target in _targets(text):
            path = _repo_path(f.src_uri, target, docs_dir, root)
            if path is None or path in added:
                continue
            added.add(path)
            new = File.generated(config, f"{REPO_PREFIX}/{path}", abs_src_path=str(root / path))
            files.append(new)
            if path.endswith(".md"):
                todo.append(new)
    return files


def on_page_markdown(markdown, page, config, files):
    """Rewrite links into the repository to their ``repo/`` copies; fill in the CLI's help."""
    root, docs_dir = _root(config), Path(config["docs_dir"]).resolve()
    src = page.file.src_uri

    def relink(m):
        target, _, fragment = m.group(2).partition("#")
        if "://" in target or not target or target.startswith("/"):
            return m.group(0)
        path = _repo_path(src, target, docs_dir, root)
        if path is None or src.startswith(REPO_PREFIX + "/"):
            return m.group(0)
        new = posixpath.relpath(f"{REPO_PREFIX}/{path}", posixpath.dirname(src) or ".")
        return m.group(1) + new + ("#" + fragment if fragment else "") + m.group(3)

    out, last = [], 0
    for a, b in _outside_code(markdown):
        out.append(markdown[last:a])
        out.append(LINK.sub(relink, markdown[a:b]))
        last = b
    out.append(markdown[last:])
    markdown = "".join(out)
    if HELP.search(markdown) or re.search(r"^" + re.escape(HELP_REST) + r"$", markdown, flags=re.M):
        markdown = _fill_help(markdown, config)
    return markdown


def _parsers():
    """The top-level parser and each sub-command's parser, by name (in ``COMMANDS`` order)."""
    import argparse

    from mitigate.cli import COMMANDS, build_parser

    top = build_parser()
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))  # noqa: SLF001 - argparse has no public accessor
    return top, {name: sub.choices[name] for name in COMMANDS if name in sub.choices}


def _help_block(parser) -> str:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_COLUMNS       # the same width on every machine
    try:
        text = parser.format_help()
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "```text\n" + text.rstrip() + "\n```"


def _fill_help(markdown: str, config) -> str:
    top, commands = _parsers()
    marked = {m.group(1) for p in Path(config["docs_dir"]).rglob("*.md")
              for m in HELP.finditer(p.read_text(encoding="utf-8"))}

    def fill(m):
        name = m.group(1)
        if not name:
            return _help_block(top)
        if name not in commands:
            log.warning(f"{m.group(0)}: mitigate has no command {name!r} (commands: {', '.join(commands)})")
            return m.group(0)
        return _help_block(commands[name])

    markdown = HELP.sub(fill, markdown)
    rest = [n for n in commands if n not in marked]
    body = "".join(f"\n## `mitigate {n}`\n\n{_help_block(commands[n])}\n" for n in rest)
    return re.sub(r"^" + re.escape(HELP_REST) + r"$", lambda _: body, markdown, flags=re.M)

