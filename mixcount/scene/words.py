"""The one word tokenizer for object and file names (catalog categories and containers, fallback captions).

``Donut_B0VL4BA90T_Pink`` -> ``["donut", "pink"]``: split on separators (``_ - . , / ( )`` and spaces)
and camelCase; a catalogue id (5+ letters and digits with at least one digit, such as ``B07Z5P84J2``) is
dropped; numbers are dropped too unless ``keep_numbers`` (a fallback caption keeps "mug 2").
"""

from __future__ import annotations

import re

ID_TOKEN = re.compile(r"^(?=.*\d)[A-Za-z0-9]{5,}$")  # catalogue ids such as B07Z5P84J2
_SEPARATORS = re.compile(r"[_\-\s.,/()]+")
_WORDS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+")
_WORDS_AND_NUMBERS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")


def words_of(name: str, *, keep_numbers: bool = False) -> list[str]:
    """Lower-case words of a name: split on separators and camelCase, catalogue ids dropped, numbers
    dropped unless ``keep_numbers``."""
    pattern = _WORDS_AND_NUMBERS if keep_numbers else _WORDS
    words: list[str] = []
    for token in _SEPARATORS.split(name.strip()):
        if not token or ID_TOKEN.match(token):
            continue
        words.extend(w.lower() for w in pattern.findall(token))
    return words
