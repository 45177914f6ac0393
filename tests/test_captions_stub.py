"""The offline stub captioner: colours named from real pixels / model surfaces, word bounds, determinism,
resumable `catalog caption`, caption-collision flags, --keep-collisions and the default dedupe, and the demo library's collision rate."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.captions.base import STUB_WORD_BOUNDS, CaptionInput, name_tokens
from mixcount.captions.captioning import caption_catalog, normalise_caption
from mixcount.captions.colours import colours_from_model, colours_from_render, name_rgb
from mixcount.captions.stub import StubCaptioner, proportion_word
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag, Render
from mixcount.cli import main


def _sentences(text: str) -> int:
    return sum(1 for part in text.split(". ") if part.strip())


def assert_bounds(short: str, concise: str, detailed: str) -> None:
    for tier, text in (("short", short), ("concise", concise), ("detailed", detailed)):
        lo, hi = STUB_WORD_BOUNDS[tier]
        assert lo <= len(text.split()) <= hi, (tier, text)
    assert 1 <= _sentences(detailed) <= 2 and detailed.endswith("."), detailed


def test_colour_names():
    assert name_rgb((220, 20, 30)) == "red"
    assert name_rgb((250, 250, 250)) == "white"
    assert name_rgb((10, 10, 12)) == "black"
    assert name_rgb((128, 128, 128)) == "grey"
    assert name_rgb((20, 30, 90)) == "navy"
    assert name_rgb((30, 90, 220)) == "blue"
    assert name_rgb((40, 160, 60)) == "green"
    assert name_rgb((240, 200, 20)) == "yellow"
    assert name_rgb((120, 70, 30)) == "brown"
    assert name_rgb((245, 140, 20)) == "orange"


def test_colours_from_rgba_and_rgb_renders(tmp_path: Path):
    rgba = Image.new("RGBA", (100, 100), (0, 0, 0, 0))
    rgba.paste((200, 30, 30, 255), (10, 10, 66, 90))  # 70 % of the object red
    rgba.paste((250, 250, 250, 255), (66, 10, 90, 90))  # 30 % white (opaque: part of the object)
    rgba.save(tmp_path / "a.png")
    c = colours_from_render(tmp_path / "a.png")
    assert c.names == ("red", "white") and c.source == "render"
    assert c.shares[0] == pytest.approx(0.7, abs=0.02)

    clear = Image.new("RGBA", (10, 10), (0, 0, 0, 0))  # nothing opaque: no colours, not "black"
    clear.save(tmp_path / "clear.png")
    assert colours_from_render(tmp_path / "clear.png").names == ()

    rgb = Image.new("RGB", (100, 100), (255, 255, 255))  # white background is not the object
    rgb.paste((30, 90, 220), (40, 40, 60, 60))
    rgb.save(tmp_path / "b.png")
    assert colours_from_render(tmp_path / "b.png").names == ("blue",)


def _coloured_glb(path: Path, mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> Path:
    mesh.visual.vertex_colors = np.tile([*rgb, 255], (len(mesh.vertices), 1))
    mesh.export(path)
    return path


def test_colours_from_model_vertex_colours_and_texture(tmp_path: Path):
    glb = _coloured_glb(tmp_path / "v.glb", trimesh.creation.box((0.1, 0.05, 0.02)), (30, 160, 50))
    assert colours_from_model(glb).names == ("green",)

    sphere = trimesh.creation.icosphere(2, 0.05)
    tex = Image.new("RGB", (32, 32), (240, 200, 20))
    tex.paste((20, 20, 20), (0, 0, 32, 12))  # a dark band
    uv = np.random.default_rng(0).random((len(sphere.vertices), 2))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=tex, baseColorFactor=[255, 255, 255, 255])
    sphere.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    sphere.export(tmp_path / "t.glb")
    names = colours_from_model(tmp_path / "t.glb").names
    assert names[0] == "yellow" and "black" in names


def test_name_tokens_drop_ids():
    assert name_tokens("Ball_B07XYZ12_SoftVolleyball") == ["ball", "soft", "volleyball"]
    assert name_tokens("Marker_B0C1234_v2") == ["marker"]


def _item(**kw) -> CaptionInput:
    base = dict(object_id=1, name="Ball_B01_Volleyball", category="ball", dims=(0.2, 0.2, 0.2),
                watertight=True, volume=0.0042, face_count=5000)
    base.update(kw)
    return CaptionInput(**base)


def test_stub_is_grounded_deterministic_and_within_bounds(tmp_path: Path):
    stub = StubCaptioner("stub-v1")
    glb = _coloured_glb(tmp_path / "b.glb", trimesh.creation.icosphere(2, 0.1), (240, 200, 20))
    item = _item(model_path=str(glb)).with_measured_colours("model")
    r = stub.caption(item)
    assert r == stub.caption(item)
    assert_bounds(r.short, r.concise, r.detailed)
    assert r.short == "yellow volleyball"
    # every word of the short caption comes from a fact: a measured colour and the name's noun
    assert r.concise == "Plain yellow volleyball" and r.detailed == "A plain yellow volleyball. It is plain yellow all over."
    for text in (r.short, r.concise, r.detailed):  # no mesh facts, no sizes: scenes rescale every class
        assert not any(w in text for w in ("cm", "mm", "measures", "surface", "watertight", "parts", "%", "shape with"))

    marker = stub.caption(_item(name="Marker_X1_Sharpie", category="marker", dims=(0.014, 0.014, 0.14),
                                volume=0.014**2 * 0.785 * 0.14))
    assert_bounds(marker.short, marker.concise, marker.detailed)
    assert marker.concise.startswith("Slender") and "marker" in marker.short  # a shape word a person uses
    assert proportion_word((0.1, 0.1, 0.1)) is None and proportion_word((0.3, 0.05, 0.05)) == "slender"
    assert proportion_word((0.3, 0.2, 0.02)) == "flat"


def test_the_name_wins_colour_compound_and_proper_nouns(tmp_path: Path):
    """The name's colour words beat the texture's mean (a dark print on white still is a "Black bowl"), its
    compound noun and the capitals of a proper noun stay, and its filler and tags go."""
    stub = StubCaptioner("stub-v1")
    sphere = trimesh.creation.icosphere(2, 0.05)
    tex = Image.new("RGB", (32, 32), (245, 245, 245))
    tex.paste((15, 15, 15), (0, 0, 32, 8))  # a black band on a white bowl
    uv = np.random.default_rng(0).random((len(sphere.vertices), 2))
    sphere.visual = trimesh.visual.TextureVisuals(
        uv=uv, material=trimesh.visual.material.PBRMaterial(baseColorTexture=tex, baseColorFactor=[255] * 4))
    sphere.export(tmp_path / "bowl.glb")
    bowl = stub.caption(_item(name="Black bowl", category="kitchenware", textured=True, dims=(0.15, 0.15, 0.06),
                              model_path=str(tmp_path / "bowl.glb")).with_measured_colours("model"))
    assert bowl.short == "black bowl" and "white" in bowl.concise  # the name's colour, then what it leaves out
    ice = stub.caption(_item(name="Ice-cream dispenser (high-res)", category="kitchenware",
                             model_path=str(_coloured_glb(tmp_path / "i.glb", trimesh.creation.box((0.1,) * 3),
                                                          (200, 30, 30)))).with_measured_colours("model"))
    assert ice.short == "red ice-cream dispenser" and "high" not in ice.detailed
    bunny = stub.caption(_item(name="Stanford bunny", category="animal",
                               model_path=str(_coloured_glb(tmp_path / "s.glb", trimesh.creation.box((0.1,) * 3),
                                                            (240, 240, 240)))).with_measured_colours("model"))
    assert bunny.short == "white Stanford bunny" and "Stanford bunny" in bunny.detailed


@pytest.mark.parametrize(
    "name,category,dims,watertight",
    [
        ("X", "object", (0.0, 0.0, 0.0), None),
        ("Toy_B0C_TyrannosaurusRexFigureWithMovingArms", "toy figure", (0.1, 0.03, 0.08), False),
        ("Plate_1", "plate", (0.25, 0.25, 0.02), False),
    ],
)
def test_stub_bounds_hold_for_odd_inputs(name, category, dims, watertight):
    r = StubCaptioner("stub-v1").caption(_item(name=name, category=category, dims=dims, watertight=watertight, volume=None))
    assert_bounds(r.short, r.concise, r.detailed)


def _library(catalog, tmp_path: Path) -> dict[str, int]:
    """Five real GLBs with renders: two exact copies (a, e), others distinct."""
    specs = {
        "a": ("ball", "Ball_B01_Volleyball", trimesh.creation.icosphere(2, 0.1), (240, 200, 20)),
        "b": ("marker", "Marker_B02_Sharpie", trimesh.creation.cylinder(0.008, 0.14), (20, 40, 200)),
        "c": ("plate", "Plate_B03_Dinner", trimesh.creation.cylinder(0.12, 0.02), (250, 250, 250)),
        "d": ("toy", "Toy_B04_Dinosaur", trimesh.creation.box((0.1, 0.04, 0.06)), (120, 80, 40)),
        "e": ("ball", "Ball_B05_Volleyball", trimesh.creation.icosphere(2, 0.1), (240, 200, 20)),
    }
    ids = {}
    with catalog.session() as s:
        for key, (cat, name, mesh, rgb) in specs.items():
            glb = _coloured_glb(tmp_path / f"{name}.glb", mesh, rgb)
            ext = mesh.extents
            obj = CatalogObject(source="folder", source_id=name, name=name, category=cat, model_path=str(glb),
                                dim_x=ext[0], dim_y=ext[1], dim_z=ext[2], watertight=mesh.is_watertight,
                                volume=mesh.volume, face_count=len(mesh.faces))
            s.add(obj)
            s.flush()
            if key == "b":  # a render wins over the model's colours
                png = tmp_path / "render_b.png"
                img = Image.new("RGBA", (64, 64), (0, 0, 0, 0))
                img.paste((200, 30, 30, 255), (20, 4, 44, 60))
                img.save(png)
                s.add(Render(object_id=obj.id, view="canonical", path=str(png), width=64, height=64))
            ids[key] = obj.id
        s.commit()
    return ids


def test_caption_command_resumes_flags_collisions_and_dedupes(catalog, db_url, tmp_path, capsys):
    ids = _library(catalog, tmp_path)
    db = db_url.removeprefix("sqlite:///")
    assert main(["--db", db, "--set", "captions.colour_source=render", "catalog", "caption",
                 "--keep-collisions", "--json"]) == 0  # flag only, for a person to review
    first = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (first["captioned"], first["skipped"], first["failed"], first["excluded"]) == (5, 0, 0, 0)
    assert first["collision_pairs"] == 1 and first["objects_in_collision"] == 2

    with catalog.session() as s:
        sets = {cs.object_id: cs for cs in s.scalars(select(CaptionSet))}
        flags = s.scalars(select(Flag).where(Flag.kind == "caption_collision")).all()
    assert "red" in sets[ids["b"]].short  # colour_source=render: from the render, not the blue model
    assert {(f.object_id, f.pair_object_id) for f in flags} == {(ids["a"], ids["e"]), (ids["e"], ids["a"])}
    assert all(cs.prompt_version == "stub-v3" and cs.active for cs in sets.values())
    texts = [normalise_caption(cs.short) for k, cs in sets.items() if k not in (ids["e"],)]
    assert len(texts) == len(set(texts))

    assert main(["--db", db, "catalog", "caption", "--keep-collisions", "--json"]) == 0  # resumable: nothing to do
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (again["captioned"], again["skipped"], again["excluded"]) == (0, 5, 0)
    with catalog.session() as s:
        assert s.get(CatalogObject, ids["e"]).status == "active"

    # the default resolves the collision (the paper's rule)
    assert main(["--db", db, "--set", "captions.stub_prompt_version=stub-v4", "catalog", "caption", "--json"]) == 0
    third = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (third["captioned"], third["excluded"]) == (5, 1)
    with catalog.session() as s:
        statuses = {o.id: o.status for o in s.scalars(select(CatalogObject))}
        active = s.scalars(select(CaptionSet).where(CaptionSet.active.is_(True))).all()
        total = len(s.scalars(select(CaptionSet)).all())
    assert statuses[ids["e"]] == "excluded" and statuses[ids["a"]] == "active"
    assert total == 10 and len(active) == 5 and {cs.prompt_version for cs in active} == {"stub-v4"}

    # a later run keeps the excluded copy's flag (the reason it was dropped) but has nothing left to resolve;
    # --dedupe is still accepted (it names the default)
    assert main(["--db", db, "--set", "captions.stub_prompt_version=stub-v4", "catalog", "caption", "--dedupe"]) == 0
    readable = capsys.readouterr()  # without --json: a readable summary on stdout, no JSON, no Python dict
    assert readable.out.startswith("captioned 0, skipped 4, failed 0 of 4 active objects")  # e was excluded
    assert "by tier: short" in readable.out and "{" not in readable.out
    assert "\ncaption collisions: 0 pairs over 0 objects" in readable.out
    with catalog.session() as s:
        kept_flags = s.scalars(select(Flag).where(Flag.kind == "caption_collision")).all()
    assert {(f.object_id, f.pair_object_id) for f in kept_flags} == {(ids["a"], ids["e"]), (ids["e"], ids["a"])}

    assert main(["--db", db, "catalog", "split", "--seed", "3", "--json"]) == 0
    split = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert split["leaks"] == [] and sum(split["totals"].values()) == 4


def test_demo_library_captions_are_distinct(tmp_path, catalog):
    """All tiers within bounds; < 5 % of distinct objects share a caption before dedupe. The generator's
    planted exact copies and rescaled copies are the same object (a duplicate group for curation): they
    may collide, and exact copies must; recoloured twins must not."""
    from mixcount.catalog import ingest
    from mixcount.config import load_config
    from mixcount.demo import library as demo

    root = tmp_path / "demo"
    truth = demo.generate_demo_library(root, seed=0, n_objects=40)
    ingest.ingest_paths(catalog, [root], config=load_config(["quick"], ["ingest.workers=1"]))
    summary = caption_catalog(catalog, StubCaptioner("stub-v1"), concurrency=2, colour_source="model", dedupe=False)
    assert summary.failed == 0 and summary.captioned >= 40 and summary.excluded == 0
    with catalog.session() as s:
        rows = s.execute(
            select(CatalogObject, CaptionSet).join(CaptionSet, CaptionSet.object_id == CatalogObject.id)
            .where(CaptionSet.active.is_(True))
        ).all()
        flagged = {(f.object_id, f.pair_object_id) for f in s.scalars(select(Flag).where(Flag.kind == "caption_collision"))}
    for _, cs in rows:
        assert_bounds(cs.short, cs.concise, cs.detailed)
    by_folder = {Path(o.model_path).parent.name: o.id for o, _ in rows}
    pair = lambda entry: frozenset((by_folder[entry[0]], by_folder[entry[1]]))  # noqa: E731
    direct = [pair(e) for key in ("exact_copies", "rescales", "turned_rescales", "retessellated", "other_source",
                                  "remeshed", "unit_changes", "rebaked", "split_parts")  # one object, republished
              for e in truth.get(key, ()) if e[0] in by_folder and e[1] in by_folder]
    # two republications of one original are the same object too (the copy and the remesh of one can): the
    # captions carry no size words any more (scenes rescale), so only the groups' closure tells them apart
    from mixcount.catalog.grouping import connected_groups

    same = {frozenset((a, b)) for g in connected_groups([tuple(sorted(p)) for p in direct]) for a in g for b in g
            if a != b}
    shorts = {o.id: normalise_caption(cs.short) for o, cs in rows}
    for e in truth["exact_copies"]:
        a, b = sorted(pair(e))
        assert (a, b) in flagged and (b, a) in flagged
    for e in truth["recolours"]:
        a, b = sorted(pair(e))
        assert shorts[a] != shorts[b]
    colliding: set[int] = set()
    for tier in ("short", "concise", "detailed"):
        seen: dict[str, list[int]] = {}
        for o, cs in rows:
            seen.setdefault(normalise_caption(getattr(cs, tier)), []).append(o.id)
        for group in seen.values():
            for a in group:
                if any(frozenset((a, b)) not in same for b in group if b != a):
                    colliding.add(a)
    assert len(colliding) / len(rows) < 0.05, (len(colliding), len(rows))


def test_corrupt_render_falls_back_to_model_colours(tmp_path: Path):
    glb = _coloured_glb(tmp_path / "g.glb", trimesh.creation.box((0.05, 0.05, 0.05)), (30, 160, 50))
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not really a png")
    item = CaptionInput(object_id=3, name="Block_1", category="block", dims=(0.05, 0.05, 0.05),
                        model_path=str(glb), render_path=bad).with_measured_colours("render")
    assert item.colours.names == ("green",) and item.colours.source == "model"


def test_colour_source_order(tmp_path: Path):
    glb = _coloured_glb(tmp_path / "m.glb", trimesh.creation.box((0.05, 0.05, 0.05)), (30, 90, 220))
    png = tmp_path / "r.png"
    img = Image.new("RGBA", (20, 20), (0, 0, 0, 0))
    img.paste((200, 30, 30, 255), (5, 5, 15, 15))
    img.save(png)
    item = CaptionInput(object_id=4, name="Box", category="box", dims=(0.05, 0.05, 0.05), model_path=str(glb),
                        render_path=png)
    assert item.with_measured_colours("model").colours.names == ("blue",)
    assert item.with_measured_colours("render").colours.names == ("red",)
    no_model = CaptionInput(object_id=5, name="Box", category="box", dims=(0.05, 0.05, 0.05),
                            model_path=str(tmp_path / "missing.usdz"), render_path=png)
    assert no_model.with_measured_colours("model").colours.source == "render"
    with pytest.raises(ValueError):
        item.with_measured_colours("guess")


class _MeasuringStub(StubCaptioner):
    """The stub plus the mesh facts and size stub-v2 wrote: what the shared check must reject."""

    def caption(self, item: CaptionInput):  # type: ignore[no-untyped-def]
        r = super().caption(item)
        return type(r)(short=r.short, concise=r.concise + " with an open surface",
                       detailed=r.detailed + " It measures about 12 cm across.", raw=r.raw)


def test_a_caption_breaking_the_rules_is_rejected_with_the_reason(catalog, tmp_path: Path):
    """The shared caption check runs on every captioner's output in `caption_catalog`: a caption with mesh
    facts or a size is not stored; a caption_failures row says which rule it broke, tier by tier."""
    from mixcount.catalog.models import CaptionFailure

    ids = _library(catalog, tmp_path)
    summary = caption_catalog(catalog, _MeasuringStub("stub-bad"), concurrency=1, colour_source="model",
                              dedupe=False)
    assert (summary.captioned, summary.failed) == (0, len(ids))
    with catalog.session() as s:
        failures = s.scalars(select(CaptionFailure)).all()
        assert s.scalars(select(CaptionSet)).all() == []
    assert len(failures) == len(ids)
    for f in failures:
        assert f.error.startswith("caption check: ")
        assert "concise mesh_fact (mesh fact 'open surface')" in f.error
        assert "detailed absolute_size" in f.error


@pytest.mark.parametrize("name,words,colours", [
    ("Ice-cream dispenser", ("ice-cream", "dispenser"), ()),
    ("Stanford bunny (high-res)", ("Stanford", "bunny"), ()),
    ("Siamese cat", ("Siamese", "cat"), ()),
    ("Cheese box", ("cheese", "box"), ()),
    ("Red Ceramic Mug", ("red", "ceramic", "mug"), ("red",)),
    ("Orange juice carton", ("orange", "juice", "carton"), ("orange",)),
    ("Ketchup bottle (blue recolour)", ("ketchup", "bottle"), ("blue",)),
    ("Teddy bear convex-hull approximation", ("teddy", "bear"), ()),
    ("Large white mug", ("white", "mug"), ("white",)),
    ("Clear glass jar", ("clear", "glass", "jar"), ()),
    ("LEGO brick 2x4", ("LEGO", "brick"), ()),
    ("Teddy2_VHACD_CHs", ("teddy",), ()),
    ("Ball_B01_Volleyball", ("volleyball",), ()),
])
def test_name_phrase_keeps_what_the_name_says(name, words, colours):
    from mixcount.captions.nouns import name_phrase

    phrase = name_phrase(name, "misc")
    assert (phrase.words, phrase.colours) == (words, colours)


@pytest.mark.parametrize("name,dims,rgb", [
    ("Plain sphere", (0.1, 0.1, 0.1), (200, 30, 30)),  # plain and red: "plain" was said twice in the concise tier
    ("Long bench", (1.2, 0.3, 0.45), (120, 80, 40)),  # long box: "long" was said twice
    ("Flat washer", (0.03, 0.03, 0.003), (180, 180, 180)),  # flat: "flat" was said twice
])
def test_a_word_the_name_says_is_not_said_again(tmp_path: Path, name, dims, rgb):
    """A name written by a person may carry the finish or shape word the captioner adds ("Plain sphere",
    "Long bench", "Flat washer"): said twice, the caption check rejected it as a repeated word and the
    object got no caption (found with pybullet's sphere_smooth.obj in a folder "Plain sphere")."""
    from mixcount.captions.check import check_tiers_text

    model = _coloured_glb(tmp_path / "m.glb", trimesh.creation.box(dims), rgb)
    got = StubCaptioner("stub-v1").caption(_item(name=name, category="object", dims=dims,
                                                 model_path=str(model)).with_measured_colours("model"))
    tiers = {"short": got.short, "concise": got.concise, "detailed": got.detailed}
    warnings = check_tiers_text(tiers, name=name, category="object", captioner="stub")
    assert [w for w in warnings if w["kind"] == "repeated_word"] == [], (tiers, warnings)
    assert name.split()[0].lower() in got.concise.lower().split(), tiers
