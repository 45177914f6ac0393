"""Caption text rules: the comparison key and size-qualified captions (the qualifier replaces the size word)."""

from __future__ import annotations

import pytest

from mixcount.captions.captioning import normalise_caption as catalog_normalise
from mixcount.scene.caption_text import normalise_caption, size_qualified


@pytest.mark.parametrize(
    "caption, qualifier, expected",
    [
        # the captions the issue saw stacked ("Larger a large ...", "Larger large ...")
        ("a large patterned white and green milk bottle", "larger", "a larger patterned white and green milk bottle"),
        ("large white and green bottle", "larger", "larger white and green bottle"),
        ("bottle", "larger", "larger bottle"),
        # the offline captioner's three tiers (capitalised concise / detailed)
        ("white and green bottle", "smaller", "smaller white and green bottle"),
        ("Large white and green bottle with a slender shape", "smaller",
         "Smaller white and green bottle with a slender shape"),
        ("A large patterned white and green milk bottle with a long shape. It measures about 24 cm by 7 cm "
         "across and 25 cm tall, with a small cap.", "smaller",
         "A smaller patterned white and green milk bottle with a long shape. It measures about 24 cm by 7 cm "
         "across and 25 cm tall, with a small cap."),
        ("A hand-sized plain white mug", "larger", "A larger plain white mug"),
        ("A very large plain black tray, used as a container.", "smaller",
         "A smaller plain black tray, used as a container."),
        ("Tiny red die with a compact shape", "larger", "Larger red die with a compact shape"),
        # articles agree with the new word
        ("An apple", "smaller", "A smaller apple"),
        ("an enormous orange", "smaller", "a smaller orange"),
        ("a small orange", "larger", "a larger orange"),
        ("the small red car", "larger", "the larger red car"),
        ("one little lego brick", "larger", "one larger lego brick"),
        # intensifiers, compounds and runs of size words go with the size word
        ("a very large mug", "smaller", "a smaller mug"),
        ("extra-large tray", "smaller", "smaller tray"),
        ("a medium-sized blue can", "smaller", "a smaller blue can"),
        ("small tiny bead", "larger", "larger bead"),
        ("a big, round bowl", "smaller", "a smaller, round bowl"),
        ("a larger white mug", "smaller", "a smaller white mug"),
        # no size word in the leading noun phrase: the qualifier goes in front of it
        ("golden yellow apple", "smaller", "smaller golden yellow apple"),
        ("a white bottle with a small cap", "larger", "a larger white bottle with a small cap"),
        ("a red mug on a large saucer", "smaller", "a smaller red mug on a large saucer"),
        ("Fancy tomato ketchup toy", "larger", "Larger fancy tomato ketchup toy"),
        ("LEGO brick", "larger", "Larger LEGO brick"),
        ("a Big Ben model", "smaller", "a smaller Big Ben model"),
        ("MINI Cooper toy car", "larger", "Larger MINI Cooper toy car"),
        ("a 3.5 cm long screw", "larger", "a larger 3.5 cm long screw"),
        ("small-batch coffee bag", "larger", "larger small-batch coffee bag"),
        ("  bowl  ", "smaller", "smaller bowl"),
        ("", "larger", "larger"),
        ("apple", None, "apple"),
    ],
)
def test_size_qualified_replaces_the_size_word(caption, qualifier, expected):
    assert size_qualified(caption, qualifier) == expected


def test_size_qualified_never_stacks_two_size_words():
    sizes = ["small", "large", "big", "tiny", "little", "huge", "very large", "hand-sized", "mini"]
    for size in sizes:
        for template in ("{s} white mug", "a {s} white mug", "A {s} white mug with a handle. It is glossy.",
                         "an {s} white mug"):
            for q in ("larger", "smaller"):
                out = size_qualified(template.format(s=size), q)
                words = out.lower().replace(",", " ").replace(".", " ").split()
                assert q in words and not set(sizes) & set(words), (template, size, out)
                assert " an larger" not in out.lower() and " an smaller" not in out.lower()
                assert not out.lower().startswith(("an larger", "an smaller")), out


def test_normalise_caption_key():
    assert normalise_caption("  White  Bowl. ") == "white bowl"
    assert normalise_caption("white bowl") == normalise_caption("WHITE BOWL.")
    assert normalise_caption("white bowl") != normalise_caption("white bowls")
    assert catalog_normalise is normalise_caption  # one rule for the catalog and the sampler
