"""What the objects a compose run draws lack, said once at the start with the command that fixes it.

Compose runs on a catalog that was only ingested and split, and that is allowed: captions fall back to
the object's name (:func:`mixcount.scene.object_records.fallback_captions`: "larger good nail" from a file
``good_nail.stl``) and an object without a canonical render has no external exemplar under
``OUT/exemplars/external/``. Issue 56: a run did both without a word. :func:`missing_steps` names, for
the split's objects (the counted classes and distractors are drawn from them), how many were never
captioned or rendered, a few names, and the command; compose and its dry run print the lines once.
"""

from __future__ import annotations

from typing import Any, Sequence

FEW = 3  # object names quoted per line


def _names(objs: Sequence[Any]) -> str:
    shown = ", ".join(repr(str(o.name)) for o in objs[:FEW])
    return shown + (f" and {len(objs) - FEW} more" if len(objs) > FEW else "")


def uncaptioned(obj: Any) -> bool:
    """Whether the object's captions are the name-derived fallback (no caption set holds it)."""
    from mixcount.scene.object_records import fallback_captions

    return bool(obj.captions == fallback_captions(str(obj.name), str(obj.category or "")))


def missing_steps(pool: Sequence[Any], split: str) -> list[str]:
    """One line per step the split's objects miss (captions, canonical renders); empty when none."""
    objs = [o for o in pool if getattr(o, "split", None) == split]
    if not objs:
        return []
    lines = []
    no_caption = [o for o in objs if uncaptioned(o)]
    if no_caption:
        example = no_caption[0].captions.concise
        lines.append(
            f"{len(no_caption)} of {len(objs)} objects of split {split!r} were never captioned ({_names(no_caption)}): "
            f"their prompts fall back to file names (e.g. {example!r}); run `mixcount catalog caption` first")
    no_render = [o for o in objs if not getattr(o, "render_path", None)]
    if no_render:
        lines.append(
            f"{len(no_render)} of {len(objs)} objects of split {split!r} have no canonical render ({_names(no_render)}): "
            "no external exemplar is written for them; run `mixcount catalog render` first")
    return lines
