"""Caption text rules shared by the catalog and the scene sampler (pure string functions, no I/O).

* :func:`normalise_caption`: the key two captions are compared by (case, whitespace and a trailing full
  stop do not count). ``catalog caption`` flags collisions with it; the sampler keeps colliding objects
  out of one scene with it.
* :func:`size_qualified`: the caption of an object shown at two sizes in one scene ("larger" / "smaller").
  The qualifier takes the place of the caption's own size word in its leading noun phrase ("a large white
  bottle" -> "a larger white bottle", "very large mug" -> "larger mug"), or goes in front of the noun
  phrase when there is none ("bottle" -> "larger bottle", "An apple" -> "A smaller apple"). Size words
  after the noun phrase ("... bottle with a small cap") describe a part and stay.
"""

from __future__ import annotations

import re
from typing import Optional


def normalise_caption(text: str) -> str:
    """Case- and whitespace-insensitive key of a caption (a trailing full stop does not count)."""
    return " ".join(text.lower().split()).rstrip(". ")


# Absolute and relative size words, with an optional intensifier ("very large", "extra-small") and any
# "<word>-sized" / "<word>-size" compound ("hand-sized", "medium-size", "bite-sized").
_SIZE_CORE = (
    r"(?:small|large|big|tiny|little|huge|giant|mini|miniature|medium|oversized|jumbo|massive|enormous|"
    r"petite|teeny|larger|smaller|bigger|largest|smallest|biggest|[a-z]+-siz(?:e|ed))"
)
_INTENSIFIER = r"(?:(?:very|extra|super|quite|rather|fairly|relatively|slightly|really|somewhat)[\s-]+)?"
_SIZE = _INTENSIFIER + _SIZE_CORE
_SIZE_RUN = re.compile(rf"(?<![\w-]){_SIZE}(?:[\s,]+(?:and\s+)?{_SIZE})*(?![\w-])", re.IGNORECASE)

# Where the leading noun phrase ends: a preposition or clause word, or the end of a sentence / aside.
_PHRASE_END = re.compile(
    r"\b(?:with|featuring|having|that|which|who|whose|on|in|inside|of|for|from|containing|showing|has|have|"
    r"is|are|was|were|where|under|over|next|beside|near|used)\b|[.;:!?()](?=\s|$)|[;:()]|\s[-\u2013\u2014]\s",
    re.IGNORECASE,
)
_DETERMINER = re.compile(r"^(a|an|the|one|this)\s+", re.IGNORECASE)


def _article_for(article: str, next_word: str) -> str:
    """``a``/``an`` agreeing with ``next_word`` (the case of ``article`` kept); other words unchanged."""
    if article.lower() not in ("a", "an"):
        return article
    want = "an" if next_word[:1].lower() in "aeiou" else "a"
    return want.capitalize() if article[:1].isupper() else want


def _fix_article_before(text: str, at: int) -> str:
    """Make an "a"/"an" directly before position ``at`` agree with the word starting there."""
    m = re.search(r"(?<![\w-])(a|an)(\s+)$", text[:at], re.IGNORECASE)
    if not m:
        return text
    fixed = _article_for(m.group(1), text[at:])
    return text[: m.start(1)] + fixed + text[m.end(1):]


def size_qualified(caption: str, qualifier: Optional[str]) -> str:
    """``caption`` as the ``qualifier`` ("larger" / "smaller") copy of its object; see the module docstring.

    The qualifier follows the case of the place it takes: at the start of a capitalised caption it is
    capitalised ("Large white mug" -> "Larger white mug"), elsewhere lower case. A capitalised size word
    inside the text is taken for a name ("a Big Ben model") and left alone.
    """
    if not qualifier:
        return caption
    word = qualifier.strip().lower()
    text = caption.strip()
    if not text:
        return word
    head_end = next((m.start() for m in _PHRASE_END.finditer(text) if m.start() > 0), len(text))
    for m in _SIZE_RUN.finditer(text, 0, head_end):
        token = m.group(0)
        at_start = m.start() == 0
        if token[:1].isupper() and not at_start:
            continue  # a name, not a size ("a Big Ben model")
        if token.isupper() and len(token) > 1:
            continue  # an acronym or brand ("MINI")
        new = word.capitalize() if token[:1].isupper() else word
        out = text[: m.start()] + new + text[m.end():]
        return _fix_article_before(out, m.start())
    det = _DETERMINER.match(text)
    if det:
        article = _article_for(det.group(1), word)
        return f"{article}{text[len(det.group(1)):det.end()]}{word} {text[det.end():]}"
    first = text.split()[0]
    if text[:1].isupper():
        if not first[1:2].isupper():  # "Fancy toy" -> "Larger fancy toy"; "LEGO brick" keeps its capitals
            text = text[:1].lower() + text[1:]
        return f"{word.capitalize()} {text}"
    return f"{word} {text}"
