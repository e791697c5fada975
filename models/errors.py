"""Exception types shared by the whole workbench, and the cap on what an error message quotes.

The CLI turns :class:`ConfigError`, :class:`DataError` and :class:`SolverFailure` into a single
line on stderr and exit code 2, and :class:`PluginError` (a controller or estimator that broke
its contract) into a single line and exit code 1.

Every message is capped when the error is made (:func:`shorten`): a value quoted in it is cut
to about :data:`QUOTE_LIMIT` characters with its size said, so an array of 100,000 numbers in
the wrong place gives one short line (``got [0.0, 1.5, 3.0, ...] (100000 items)``), never
megabytes.
"""

from __future__ import annotations

__all__ = ["ConfigError", "DataError", "SolverFailure", "PluginError", "shorten", "quote", "QUOTE_LIMIT"]

#: at most this many characters of one quoted value in a message
QUOTE_LIMIT = 80
_PAIRS = {"[": "]", "(": ")", "{": "}"}
_CLOSERS = set(_PAIRS.values())


def _items(span: str) -> int:
    """Top-level items of a bracketed repr such as ``[1, [2, 3], 'a,b']``."""
    depth, n, quote_ch, empty = 0, 1, None, True
    for ch in span[1:-1]:
        if quote_ch:
            if ch == quote_ch:
                quote_ch = None
            continue
        if ch in "'\"":
            quote_ch = ch
        elif ch in _PAIRS:
            depth += 1
        elif ch in _PAIRS.values():
            depth -= 1
        elif ch == "," and depth == 0:
            n += 1
        if not ch.isspace():
            empty = False
    return 0 if empty else n


def _matches(text: str) -> dict[int, int]:
    """``{index of an opening bracket: index of its closing one}`` in one pass (quotes
    respected; an unbalanced bracket has no entry)."""
    match, stack, quote_ch = {}, [], None
    for j, ch in enumerate(text):
        if quote_ch:
            if ch == quote_ch:
                quote_ch = None
        elif ch in "'\"" and stack:
            quote_ch = ch
        elif ch in _PAIRS:
            stack.append(j)
        elif ch in _CLOSERS:
            if stack and _PAIRS[text[stack[-1]]] == ch:
                match[stack.pop()] = j
            else:
                stack.clear()
    return match


def shorten(text: str, limit: int = QUOTE_LIMIT, run_limit: int = 3 * QUOTE_LIMIT) -> str:
    """``text`` with every bracketed span (a list, tuple or table quoted in it) longer than
    ``limit`` characters cut to its head and ``(N items)``, and every other run of more than
    ``run_limit`` characters without a space (a long string; a file path is shorter) cut to its
    head and ``(N characters)``.  Short text is returned unchanged."""
    if len(text) <= limit:
        return text
    n = len(text)
    long_span = {i: j for i, j in _matches(text).items() if j - i + 1 > limit}
    out, i = [], 0
    while i < n:
        j = long_span.get(i)
        if j is not None:
            span = text[i:j + 1]
            head = span[:limit - 8].rsplit(",", 1)[0]
            out.append(f"{head}, ...{span[-1]} ({_items(span)} items)")
            i = j + 1
        elif text[i].isspace():
            out.append(text[i])
            i += 1
        else:
            j = i + 1
            while j < n and not text[j].isspace() and j not in long_span:
                j += 1
            out.append(f"{text[i:i + limit - 8]}... ({j - i} characters)" if j - i > run_limit else text[i:j])
            i = j
    return "".join(out)


def quote(value, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)`` cut to about ``limit`` characters, with its size said when cut."""
    return shorten(repr(value), limit, limit)


class _Capped:
    """Mixin: the message is capped by :func:`shorten` when the error is made."""

    def __init__(self, *args):
        if len(args) == 1 and isinstance(args[0], str):
            args = (shorten(args[0]) if len(args[0]) > 4 * QUOTE_LIMIT else args[0],)
        super().__init__(*args)


class ConfigError(_Capped, ValueError):
    """A parameter file, scenario or option is malformed (names the field)."""


class DataError(_Capped, ValueError):
    """A log or measurement is malformed (names the column and row)."""


class SolverFailure(_Capped, RuntimeError):
    """A numerical solver did not return a usable solution.

    Raised inside a controller's ``_step_impl`` or an estimator's ``_update_impl`` it is the one
    *transient* failure: answered by that plug-in's documented fallback and counted.  Any other
    exception fails the run (:class:`PluginError`)."""


class PluginError(_Capped, RuntimeError):
    """A controller or estimator broke its contract: it raised (anything but SolverFailure, also
    ``SystemExit``), returned a non-finite value or the wrong type, or did not return within its
    timeout.  Its run is FAILED with this message (the exception's type and first line)."""
