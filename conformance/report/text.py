"""A frame's bytes as a report shows them: readable text, and a POSIX ``printf`` that
reproduces them byte for byte (the reproduction lines of ``run`` and ``serve``)."""

from __future__ import annotations

from ..judge.judge import Verdict
from ..judge.requests import RefusalForm
from ..spec.commands import SpecSet, error_code_text

__all__ = ["plural", "printable", "refusal_text", "shell_printf", "show"]


def shell_printf(raw: bytes) -> str:
    """A POSIX ``printf`` format that prints exactly ``raw`` (octal escapes, no bashisms)."""
    out: list[str] = []
    for b in raw:
        ch = chr(b)
        if ch == "%":
            out.append("%%")
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "'":
            out.append("'\\''")
        elif 0x20 <= b < 0x7F:
            out.append(ch)
        else:
            out.append(f"\\{b:03o}")
    return "'" + "".join(out) + "'"


def show(raw: bytes, limit: int = 400) -> str:
    text = raw[:limit].decode("utf-8", "backslashreplace")
    return text + (f"...(+{len(raw) - limit} bytes)" if len(raw) > limit else "")


def printable(text: str) -> str:
    """``text`` with every character a terminal, a CI log or XML cannot carry escaped as
    Python does (``\\x00``, ``\\x1b``, ``\\udcff``): control characters but newline and tab,
    and lone surrogates.  Every text a report holds passes through it (the cases' details,
    frames, names and reproductions), so JUnit XML is well formed by construction and
    ``grep`` never calls a log binary."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() or ch in "\n\t" else repr(ch)[1:-1] for ch in text)


def plural(n: int, word: str, many: str | None = None) -> str:
    """``n`` and ``word`` in its number: ``1 case``, ``2 cases``, ``0 cases``
    (``many``: where the plural is not ``word + "s"``)."""
    return f"{n} {word if n == 1 else many or word + 's'}"


def refusal_text(v: Verdict, specs: SpecSet) -> str:
    """How every front-end names a refusal: ``refusal, code 14 (<chapter 9 text>)``; a
    ``0`` where success is ``1`` is a failure without a code, never chapter 9's code 0
    (成功, success); a code no table has says so."""
    if v.form is RefusalForm.ZERO:
        return "refusal: 0, failed without an error code"
    if v.code is None:
        return "refusal"
    known = error_code_text(specs, v.code)
    return f"refusal, code {v.code} ({known or 'no manual table has it'})"
