"""TeX math in Markdown, typeset as MathML for viser's Markdown panels (no CDN, no images).

viser's Markdown has no math renderer, but it passes raw HTML through (its client parses it
with the browser's own HTML parser), and browsers lay out MathML natively (MathML Core:
Chromium 109+, Firefox, Safari). So each ``$...$`` (inline) or ``$$...$$`` (display) is
converted on the server, once per distinct TeX string, by :mod:`latex2mathml` (pure Python)
into a ``<math>`` element. The result is text, not a picture: it takes the panel's colour
and size, scales with the page and can be selected and read by a screen reader.

:mod:`latex2mathml` is lenient: an unknown command comes out as literal text
(``\\foo`` -> ``<mi>\\foo</mi>``), an unbalanced brace as a stray glyph, ``\\frac{a}`` as a
fraction without denominator. :func:`tex_to_mathml` checks its output and raises
:class:`MathError` on each of these, so a typo in an algorithm's equations fails a test
instead of showing TeX to a student.

Text between MathML tags is still read as Markdown by the client (``*``, ``_``, ``[`` would
start emphasis or links), so every character there other than a letter, a digit or a space
is written as a numeric character reference, which Markdown decodes and never interprets.
"""

from __future__ import annotations

import html
import re
import xml.etree.ElementTree as ET
from functools import lru_cache

__all__ = ["MathError", "tex_to_mathml", "markdown_math", "visible_text"]

_MATHML_NS = "{http://www.w3.org/1998/Math/MathML}"

#: MathML elements and the number of children each must have.
_ARITY = {"mfrac": 2, "msub": 2, "msup": 2, "msubsup": 3, "mover": 2, "munder": 2,
          "munderover": 3, "mroot": 2}
#: Token elements: a character or a word each; empty means the converter dropped something.
_TOKENS = ("mi", "mo", "mn")


class MathError(ValueError):
    """A TeX string that does not typeset (unknown command, unbalanced braces, ...)."""


def _check_braces(tex: str) -> None:
    depth = 0
    for m in re.finditer(r"\\.|[{}]", tex):
        tok = m.group()
        if tok == "{":
            depth += 1
        elif tok == "}":
            depth -= 1
            if depth < 0:
                raise MathError(f"unbalanced '}}' at character {m.start()} in ${tex}$")
    if depth:
        raise MathError(f"{depth} unclosed '{{' in ${tex}$")


def _check_tree(xml: str, tex: str) -> None:
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:  # e.g. a bare '&' that latex2mathml copies through
        raise MathError(f"${tex}$ gives malformed MathML ({exc})") from exc
    # A script with nothing before it ("m$^2$") has an empty base: allowed.
    bases = {id(el[0]) for el in root.iter() if len(el)
             and el.tag.removeprefix(_MATHML_NS) in ("msub", "msup", "msubsup")}
    for el in root.iter():
        tag = el.tag.removeprefix(_MATHML_NS)
        text = el.text or ""
        if "\\" in text:
            raise MathError(f"unknown TeX command {text.strip()!r} in ${tex}$")
        if tag in _ARITY and len(el) != _ARITY[tag]:
            raise MathError(f"<{tag}> with {len(el)} parts instead of {_ARITY[tag]} in "
                            f"${tex}$ (a missing argument?)")
        if tag in _TOKENS and not text.strip() and id(el) not in bases:
            raise MathError(f"empty <{tag}> in ${tex}$ (a construct the converter drops, "
                            f"such as \\operatorname: write \\mathrm{{...}})")


def _markdown_safe(xml: str) -> str:
    """``xml`` with the text between tags written as character references (see module)."""
    def esc(m: re.Match) -> str:
        text = html.unescape(m.group(1))
        return ">" + "".join(c if c.isascii() and (c.isalnum() or c == " ") else
                             f"&#x{ord(c):X};" for c in text) + "<"
    return re.sub(r">([^<]+)<", esc, xml)


@lru_cache(maxsize=1024)
def tex_to_mathml(tex: str, display: bool = False) -> str:
    """One TeX formula (without its ``$``) as a one-line ``<math>`` element for Markdown.

    Parameters
    ----------
    tex : the formula, e.g. ``r"\\lambda = \\lVert V b \\rVert^2 / \\sigma^2"``.
    display : a display (block) formula instead of an inline one.

    Returns
    -------
    str : ``<math xmlns="http://www.w3.org/1998/Math/MathML" display="inline">...</math>``,
        no newline, every character between tags other than ASCII letters, digits and
        spaces written as ``&#x...;``. Cached: the same TeX is converted once.

    Raises
    ------
    MathError : the formula does not typeset (unbalanced braces, an unknown command, a
        missing argument, a construct the converter drops).

    >>> tex_to_mathml("x^2").removeprefix('<math xmlns="http://www.w3.org/1998/Math/MathML" ')
    'display="inline"><mrow><msup><mi>x</mi><mn>2</mn></msup></mrow></math>'
    """
    from latex2mathml.converter import convert  # the app extra; imported when first needed

    if not tex.strip():
        raise MathError("empty formula ($$)")
    _check_braces(tex)
    try:
        xml = convert(tex, display="block" if display else "inline")
    except Exception as exc:  # latex2mathml's errors share no base class; none is hidden
        raise MathError(f"${tex}$ does not typeset: {type(exc).__name__} {exc}".rstrip()
                        ) from exc
    _check_tree(xml, tex)
    return _markdown_safe(xml.replace("\n", ""))


_DISPLAY = re.compile(r"\$\$(.+?)\$\$", re.S)
_INLINE = re.compile(r"\$([^$]+?)\$")


def markdown_math(md: str) -> str:
    """Markdown with every ``$$...$$`` (display) and ``$...$`` (inline) formula typeset as
    MathML (:func:`tex_to_mathml`); the rest unchanged.

    Raises
    ------
    MathError : a formula does not typeset, or a ``$`` is left unpaired.
    """
    md = _DISPLAY.sub(lambda m: "\n\n" + tex_to_mathml(m.group(1).strip(), True) + "\n\n", md)
    md = _INLINE.sub(lambda m: tex_to_mathml(m.group(1).strip()), md)
    rest = re.sub(r"<math\b.*?</math>", "", md, flags=re.S)
    if "$" in rest:
        raise MathError(f"unpaired '$' in: {rest[max(0, rest.index('$') - 40):][:80]!r}")
    return md


def visible_text(md: str) -> str:
    """What a reader sees of Markdown with MathML: tags removed, character references
    decoded (Markdown markers such as ``**`` and ``-`` are kept). For tests and checks.

    >>> visible_text(markdown_math(r"$\\sigma^2$ (m$^2$)"))
    'σ2 (m2)'
    """
    return html.unescape(re.sub(r"<[^>]*>", "", md))
