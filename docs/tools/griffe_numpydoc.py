"""A griffe extension (``mkdocs.yml``: the Python handler's ``extensions``): this project's
numpydoc entries read ``name : what it is`` (the description after the colon, the type in the
signature), where numpydoc proper puts a type there. Left as they are, griffe would show each
description as a type. Before a docstring is parsed, each entry line of the sections below,
``name : text`` at the section's indent, becomes ``name`` with ``text`` as the first line of its
description (more-indented continuation lines already belong to it); and a Sphinx role
(``:class:`X` ``) becomes plain code::

    Parameters                         Parameters
    ----------                         ----------
    log : a Log holding the rig's  ->  log
        inputs                             a Log holding the rig's
                                           inputs
"""

from __future__ import annotations

import re

from griffe import Extension

SECTIONS = {"parameters", "other parameters", "attributes", "returns", "yields", "receives", "raises", "warns"}
ENTRY = re.compile(r"^(?P<indent>[ \t]*)(?P<names>[^\s:][^:]*?)\s+:\s+(?P<text>\S.*)$")
UNDERLINE = re.compile(r"^[ \t]*-{3,}[ \t]*$")
# a numpydoc type proper ("int", "np.ndarray | None", "tuple[str, ...], optional"): left as it is
TYPE = re.compile(r"^[\w.]+(\[[^\]]*\])?( \| [\w.]+(\[[^\]]*\])?)*(, optional)?$")
# Sphinx roles (:class:`X`, :func:`~a.b`) read as code in Markdown
ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj|const):`~?([^`]+)`")


def rewrite(doc: str) -> str:
    """The docstring with every ``name : text`` entry line of a listed section split (module docstring)."""
    lines = doc.splitlines()
    out, section, base = [], None, None
    for i, line in enumerate(lines):
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if UNDERLINE.match(nxt) and line.strip():
            section = line.strip().lower()
            base = len(line) - len(line.lstrip())
            out.append(line)
            continue
        m = ENTRY.match(line)
        if section in SECTIONS and m and len(m.group("indent")) == base and not TYPE.match(m.group("text")):
            out.append(f"{m.group('indent')}{m.group('names')}")
            out.append(f"{m.group('indent')}    {m.group('text')}")
            continue
        out.append(line)
    return "\n".join(out)


class NumpydocEntries(Extension):
    """Rewrites the docstrings of every object griffe loads (see the module docstring)."""

    def on_instance(self, *, obj, **kwargs) -> None:   # noqa: D102 - griffe's hook
        doc = getattr(obj, "docstring", None)
        if doc is not None:
            doc.value = ROLE.sub(r"`\1`", rewrite(doc.value) if " : " in doc.value else doc.value)
