"""A catalog-shaped object pool for sampler tests: real categories, real sizes (metres), three-tier captions
in the offline captioner's style, containers, and the caption collisions a real library has (twins with
identical captions at every tier, same-category objects sharing their short caption)."""

from __future__ import annotations

from mixcount.scene.object_records import ObjectRecord
from mixcount.scene.spec import Captions

# category -> (dims in metres, colour variants); sizes of everyday captures (a die to a bottle)
_CATEGORIES: dict[str, tuple[tuple[float, float, float], tuple[str, ...]]] = {
    "apple": ((0.08, 0.078, 0.075), ("red", "green", "golden yellow", "red")),
    "banana": ((0.2, 0.045, 0.04), ("yellow", "green")),
    "orange": ((0.075, 0.075, 0.072), ("orange",)),
    "lemon": ((0.07, 0.05, 0.05), ("yellow", "pale yellow")),
    "mug": ((0.12, 0.085, 0.1), ("white", "white", "blue", "black", "light grey")),
    "bottle": ((0.07, 0.07, 0.25), ("white and green", "clear", "brown", "blue")),
    "can": ((0.066, 0.066, 0.122), ("red", "silver", "green")),
    "donut": ((0.09, 0.09, 0.03), ("pink", "brown", "white")),
    "toy car": ((0.1, 0.045, 0.04), ("red", "blue", "yellow", "black")),
    "lego brick": ((0.032, 0.016, 0.011), ("red", "blue", "yellow", "green", "white")),
    "ball": ((0.068, 0.068, 0.068), ("white", "orange", "multicoloured")),
    "spoon": ((0.17, 0.04, 0.02), ("silver", "wooden brown")),
    "screw": ((0.04, 0.008, 0.008), ("silver", "brass")),
    "die": ((0.016, 0.016, 0.016), ("white", "red")),
    "cookie": ((0.07, 0.07, 0.012), ("brown", "light brown")),
    "battery": ((0.05, 0.014, 0.014), ("copper and black", "silver")),
    "marker": ((0.14, 0.018, 0.018), ("black", "red", "blue")),
    "egg": ((0.058, 0.044, 0.044), ("white", "brown")),
    "shell": ((0.06, 0.045, 0.02), ("cream", "pink")),
    "candle": ((0.05, 0.05, 0.1), ("white", "red")),
    "plate": ((0.26, 0.26, 0.025), ("white", "blue patterned")),
    "tray": ((0.4, 0.3, 0.03), ("black", "wooden brown")),
    "bowl": ((0.16, 0.16, 0.07), ("white light grey", "white light grey", "green")),
}


def _size_word(max_dim: float) -> str:
    return "tiny" if max_dim < 0.03 else "small" if max_dim < 0.08 else "hand-sized" if max_dim < 0.2 else "large"


def library_pool(split: str = "train") -> list[ObjectRecord]:
    """63 active objects of one split (colliding captions included) plus objects that must never be drawn."""
    pool: list[ObjectRecord] = []
    oid = 1
    for cat, (dims, colours) in _CATEGORIES.items():
        for j, colour in enumerate(colours):
            scale = 1.0 + 0.08 * j  # objects of a category differ a little in size
            d = tuple(round(v * scale, 4) for v in dims)
            size = _size_word(max(d))
            # repeated colours within a category give identical captions (the twins of a real library)
            caps = Captions(
                short=f"{colour} {cat}",
                concise=f"{size} {colour} {cat}",
                detailed=f"a {size} plain {colour} {cat}, {round(max(d) * 100)} cm long",
            )
            if j and colour == colours[j - 1]:
                caps = pool[-1].captions
            pool.append(ObjectRecord(oid, f"{cat.title().replace(' ', '')}_{oid:03d}", cat, d, caps, split,
                                     f"/lib/{oid}.glb", f"h{oid:05d}"))
            oid += 1
    # a mug sharing only its short caption with another mug's, and objects outside the draw
    pool.append(ObjectRecord(oid, "Mug_shortdup", "mug", (0.11, 0.08, 0.095),
                             Captions("blue mug", "small glossy blue mug", "a small glossy blue mug with a handle"),
                             split, f"/lib/{oid}.glb", f"h{oid:05d}"))
    oid += 1
    for j in range(4):
        pool.append(ObjectRecord(oid, f"held_out_{j}", "apple", (0.08, 0.08, 0.08),
                                 Captions("red apple", "small red apple", "a small red apple"),
                                 "val" if split != "val" else "test", f"/lib/{oid}.glb", f"h{oid:05d}"))
        oid += 1
        pool.append(ObjectRecord(oid, f"excluded_{j}", "mug", (0.1, 0.08, 0.1),
                                 Captions("white mug", "small white mug", "a small white mug"),
                                 split, f"/lib/{oid}.glb", f"h{oid:05d}", status="excluded"))
        oid += 1
    return pool
