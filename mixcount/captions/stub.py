"""The offline captioner: the words a person would type into a counter's prompt box, from what is seen.

Nothing here is canned per object, and nothing comes from the mesh:

* the name wins where it knows (:func:`mixcount.captions.nouns.name_phrase`): its own words in its order
  and case ("Stanford bunny", "Ice-cream dispenser", "Orange juice carton"), its colour words kept (a
  texture's mean colour is not the object's colour: dark prints, labels, patterns), ids, source tags and
  size words dropped; a DTC folder name gives the category noun;
* colours as rendered: the dominant colours measured from the canonical render or from the material the
  way the renderer evaluates it (:mod:`mixcount.captions.colours`); beside the name's own colours they
  add only what the name does not say ("Black bowl with a white pattern");
* "patterned" for a textured object of several colours, "plain" for one colour with little variation;
* proportion words a person uses ("long", "flat", "slender"), from the ratios of the box: scale-free, so
  true in every scene; no mesh facts (surface, watertightness, parts, colour percentages) and no sizes
  (scenes rescale each class; "larger" / "smaller" come from the scene's class qualifier only).

Tiers: short = colours + noun phrase (2-5 words); concise = the phrase that picks the object out (finish,
colours, noun phrase, the name's own detail, what the name's colours leave out); detailed = one or two
sentences of appearance. ``item.tell`` > 0 (set when two different objects came out equal) adds telling
words to every tier; ``item.tone`` says "darker" / "lighter" against an object of the same colour names.
The same input always gives the same text (no randomness at all).
"""

from __future__ import annotations

import hashlib
import json

from mixcount.captions.base import CaptionInput, CaptionResult
from mixcount.captions.colours import family
from mixcount.captions.nouns import name_phrase
from mixcount.catalog.naming import singular

MAX_SHORT = 5


def proportion_word(dims: tuple[float, float, float]) -> str | None:
    """A shape word a person uses, from the box's ratios (never from its size): long, slender, flat."""
    a, b, c = sorted((abs(d) for d in dims), reverse=True)
    if a <= 0 or b <= 0:
        return None
    if a / b >= 2.2:
        return "slender" if c > 0 and b / c < 1.6 else "long"
    if c / b <= 0.3:
        return "flat"
    return None


def _distinct(names: tuple[str, ...] | list[str], taken: set[str]) -> list[str]:
    """Colour names whose family is not taken yet, one per family and none sharing a word with one kept
    ("light grey" after "light blue" would repeat "light"), in order."""
    out: list[str] = []
    seen = set(taken)
    for n in names:
        fam = family(n) or n
        if fam not in seen and not any(set(n.split()) & set(k.split()) for k in out):  # "light blue", "light grey"
            seen.add(fam)
            out.append(n)
    return out


def _listing(names: list[str]) -> str:
    if len(names) <= 1:
        return "".join(names)
    return ", ".join(names[:-1]) + " and " + names[-1]


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"


def _upper_first(text: str) -> str:
    return text[:1].upper() + text[1:]


class StubCaptioner:
    """Deterministic offline captioner (the default). See the module docstring for the rules."""

    name = "stub"
    provider = "offline"
    model = "stub"

    def __init__(self, prompt_version: str) -> None:
        """``prompt_version``: ``captions.stub_prompt_version`` (bump it to re-caption everything)."""
        self.prompt_version = prompt_version

    def caption(self, item: CaptionInput) -> CaptionResult:
        phrase = name_phrase(item.name, item.category)
        words = list(phrase.words)
        lower = [w.lower() for w in words]
        named = list(phrase.colours)  # the name's colour words: they win
        lead = [c for c in named if c not in lower]  # "(blue recolour)": said in front of the noun
        named_fams = {family(c) or c for c in named}
        measured = _distinct(item.colours.names, set())
        extra = _distinct(item.colours.names, named_fams)  # what the name's colours do not say
        # a print or pattern: an image texture on the model (a render's pixels: a varied surface)
        textured = item.colours.textured if item.colours.textured is not None else item.colours.variation >= 0.12
        # a textured object of several colours; with a name's colour, a texture whose measured colours are
        # other than the name's ("Black bowl" printed black on white)
        patterned = textured and (len(measured) >= 3 or (len(measured) >= 2 and item.colours.variation >= 0.12)
                                  or (bool(named) and bool(extra) and item.colours.variation >= 0.12))
        plain = len(measured) == 1 and item.colours.variation < 0.08
        shape = proportion_word(item.dims)
        # a word the name says already is not said again ("Plain sphere" is no "plain plain sphere")
        shape = None if shape in lower else shape
        said_patterned = patterned and "patterned" not in lower
        tone = [item.tone] if item.tone else []
        plural = singular(phrase.head) != phrase.head  # "sneakers", "headphones": no article
        detail = list(phrase.detail)

        # --- short: colours + noun phrase, 2-5 words; the name's words are never dropped before its colours
        if named:
            colour_words = lead + ([f"and {extra[0]}"] if item.tell >= 1 and extra else [])
            options = [tone + colour_words + (["patterned"] if item.tell >= 1 and said_patterned else []) + words,
                       tone + colour_words + words, tone + lead + words, lead + words]
        else:
            two = measured[:2]
            options = [tone + _listing(two).split() + ["patterned"] + words if said_patterned else [],
                       tone + _listing(two).split() + words,
                       tone + measured[:1] + (["patterned"] if said_patterned else []) + words,
                       tone + measured[:1] + words]
            if item.tell >= 1 and len(measured) >= 3:
                options.insert(0, tone + _listing(measured[:3]).split() + words)
        if item.tell >= 2 and shape:
            options = [[shape] + o for o in options if o] + options
        options += [words[-MAX_SHORT:], words[-1:]]
        short_words = next((o for o in options if o and 2 <= len(" ".join(o).split()) <= MAX_SHORT), None)
        if short_words is None:  # a one-word name and no colour measured: the finish or shape in front
            short_words = [shape or "plain"] + words[-1:]
        short = " ".join(" ".join(short_words).split())

        # --- concise: finish + colours + noun phrase + the name's detail + what the name's colours leave out
        finish = [w for w in (["patterned"] if patterned else ["plain"] if plain else []) if w not in lower]
        shape_words = [shape] if shape else []
        said_finish = finish if (patterned or not shape) else []
        extra_text = (f"a {_listing(extra[:2])} pattern" if patterned else f"{_listing(extra[:2])} details") \
            if extra else ""
        if named:
            tail = f"with {extra_text}" if extra else ""
            head = tone + shape_words + (said_finish if not extra else []) + lead + words
        else:
            tail = ""
            head = tone + shape_words + said_finish + _listing(measured[:3]).split() + words
        if detail:
            tail = " ".join(["with", *detail] + ([tail.removeprefix("with ")] if tail else []))
        concise_words = (" ".join(head) + (" " + tail if tail else "")).split()
        if len(concise_words) < 2:  # no colour measured and a one-word name: what the short tier says
            concise_words = short.split()
        concise = _upper_first(" ".join(concise_words[:12]))

        # --- detailed: one or two sentences of appearance
        body = " ".join(tone + shape_words + (finish if not (named and extra) else [])
                        + (lead + words if named else _listing(measured[:3]).split() + words))
        first = _upper_first(body) if plural else f"{_article(body).capitalize()} {body}"
        withs = [" ".join(detail)] if detail else []
        if named and extra:
            withs.append(extra_text)
        if withs:
            first += " with " + " and ".join(withs)
        second = ""
        if len(measured) >= 2:
            rest = _listing(measured[1:3])
            second = f"It is mostly {measured[0]}, with {rest} {'in a pattern' if patterned else 'areas'}."
        elif plain and measured:
            second = f"It is plain {measured[0]} all over."
        detailed = f"{first}. {second}".strip() if second else f"{first}."
        raw = json.dumps(
            {
                "short": short,
                "concise": concise,
                "detailed": detailed,
                "facts": item.facts(),
                "name_phrase": {"words": list(phrase.words), "colours": list(phrase.colours),
                                "source": phrase.source, "dropped": list(phrase.dropped)},
                "colours": item.colours.as_dict(),
                "tell": item.tell,
            },
            sort_keys=True,
        )
        return CaptionResult(short=short, concise=concise, detailed=detailed, raw=raw, attempts=1)


def response_hash(raw: str) -> str:
    return hashlib.sha256(raw.encode("utf-8")).hexdigest()
