"""How large a compose run draws the objects it asks to be counted, in pixels, against a floor (issue 70).

A quick-config scene drew its objects at 5-26 px, without a word; a counting dataset of objects that
small teaches little. The size of a counted object is the longer side of its box, in pixels of the image
(``compose.resolution``): the measure a person uses when saying an object is "20 px".

* From the plan, before anything renders (:func:`planned_object_px`): each counted object's largest
  side (``PlacedObject.size_m``, scene metres) times the camera's focal length in pixels, over the
  camera's distance from the spec. With a container that distance is the one the worker frames with
  (``paper`` framing: factor x container diagonal x the drawn jitter); without one it is the sampler's
  provisional distance over the spawn square, which the worker replaces by one over the settled pile's
  footprint. On 8 quick-config scenes (128 px, seeds 100-107, demo library) the plan's median was within
  0.8-1.3 x the rendered one (docs/scene.md, "Pixels per counted object").
* From the images (:func:`measured_object_px`): the longer side of each visible counted object's COCO
  box (distractors left out), every camera's image of the scene.

:class:`PixelSizes` holds the median and the smallest of either against ``compose.min_object_px``; the
run warns at its start when the plan's median is under the floor and its summary states both
(:mod:`mixcount.run.compose`).
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional

PLAN = "plan"
IMAGES = "images"


def focal_px(camera: Any) -> float:
    """The camera's focal length in pixels of its image width (horizontal sensor fit, square pixels)."""
    return float(camera.focal_length_mm) / float(camera.sensor_width_mm) * float(camera.resolution[0])


def planned_object_px(spec: Any) -> list[float]:
    """Expected box side (px) of each counted object of ``spec`` in each of its cameras (module docstring)."""
    out: list[float] = []
    for cam in spec.cameras:
        if not cam.distance > 0:
            continue
        f = focal_px(cam) / float(cam.distance)
        out.extend(float(o.size_m) * f for o in spec.objects if o.role == "counted")
    return out


def measured_object_px(scene_dir: Path) -> list[float]:
    """Box sides (px) of the visible counted objects in a finished scene's ``coco.json`` (empty when it
    cannot be read)."""
    try:
        coco = json.loads((Path(scene_dir) / "coco.json").read_text(encoding="utf-8"))
        return [float(max(a["bbox"][2], a["bbox"][3])) for a in coco.get("annotations", [])
                if not a.get("is_distractor")]
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return []


@dataclass
class PixelTally:
    """Box sides gathered over many scenes, kept as a histogram of whole pixels (bounded by the image
    size, not by the number of objects: a run of 100,000 scenes keeps a few hundred numbers)."""

    counts: Counter[int]
    scenes: int = 0

    @classmethod
    def empty(cls) -> "PixelTally":
        return cls(Counter())

    def add(self, sides: Iterable[float]) -> None:
        values = [max(0, int(round(v))) for v in sides]
        self.counts.update(values)
        self.scenes += 1

    @property
    def objects(self) -> int:
        return sum(self.counts.values())

    def median(self) -> Optional[float]:
        n = self.objects
        if n == 0:
            return None
        ranks = ((n - 1) // 2, n // 2)
        found: list[int] = []
        seen = 0
        for value in sorted(self.counts):
            seen += self.counts[value]
            while len(found) < 2 and ranks[len(found)] < seen:
                found.append(value)
        return (found[0] + found[1]) / 2

    def smallest(self) -> Optional[float]:
        return float(min(self.counts)) if self.counts else None

    def sizes(self, floor: float, source: str) -> "PixelSizes":
        return PixelSizes(source=source, floor=float(floor), median=self.median(), smallest=self.smallest(),
                          objects=self.objects, scenes=self.scenes)


@dataclass(frozen=True)
class PixelSizes:
    """Median and smallest box side (px) of counted objects from the plan or the images, and the floor."""

    source: str  # PLAN | IMAGES
    floor: float  # compose.min_object_px (0: no floor)
    median: Optional[float]
    smallest: Optional[float]
    objects: int
    scenes: int

    @property
    def under_floor(self) -> bool:
        """The median under the floor (None without objects or without a floor)."""
        return self.median is not None and self.floor > 0 and self.median < self.floor

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "median_px": self.median, "smallest_px": self.smallest,
                "objects": self.objects, "scenes": self.scenes, "floor_px": self.floor,
                "under_floor": self.under_floor}

    def line(self) -> str:
        """``pixels per counted object (images, 61 objects in 8 scenes): median 25 px, smallest 7 px; under
        the floor compose.min_object_px = 32 px``."""
        if self.median is None or self.smallest is None:
            return f"pixels per counted object ({self.source}): no counted object"
        where = "planned" if self.source == PLAN else "in the images"
        text = (f"pixels per counted object {where} (longer box side, {self.objects} object(s) in {self.scenes} "
                f"scene(s)): median {self.median:g} px, smallest {self.smallest:g} px")
        if self.floor <= 0:
            return text
        if self.under_floor:
            return (text + f"; the median is UNDER the floor compose.min_object_px = {self.floor:g} px: objects "
                    "this small are hard to count; raise --resolution, or draw fewer objects per scene (scene.n_objects)")
        return text + f"; at or above the floor compose.min_object_px = {self.floor:g} px"


def planned_sizes(specs: Iterable[Any], floor: float) -> PixelSizes:
    """:class:`PixelSizes` of the plan: every counted object of ``specs`` in every camera."""
    tally = PixelTally.empty()
    for spec in specs:
        tally.add(planned_object_px(spec))
    return tally.sizes(floor, PLAN)


def plan_warning(sizes: PixelSizes) -> Optional[str]:
    """The warning a run says at its start when the plan's median is under the floor, else None."""
    if not sizes.under_floor:
        return None
    return (f"objects are too small to count: the plan draws counted objects at a median of {sizes.median:g} px "
            f"(smallest {sizes.smallest:g} px, longer box side, {sizes.scenes} planned scene(s)), under "
            f"compose.min_object_px = {sizes.floor:g} px; raise --resolution, or draw fewer "
            "objects per scene (scene.n_objects)")


def _from_dict(d: Any) -> Optional[PixelSizes]:
    if not isinstance(d, dict) or not d.get("objects"):
        return None
    return PixelSizes(source=str(d["source"]), floor=float(d["floor_px"]), median=d["median_px"],
                      smallest=d["smallest_px"], objects=int(d["objects"]), scenes=int(d["scenes"]))


def summary_lines(object_px: Any) -> list[str]:
    """What a compose summary says of ``ComposeSummary.object_px``: the images the run wrote, else
    (nothing new was written) its plan; nothing when it drew no scene."""
    if not isinstance(object_px, dict):
        return []
    for key in (IMAGES, PLAN):
        sizes = _from_dict(object_px.get(key))
        if sizes is not None:
            return [sizes.line()]
    return []
