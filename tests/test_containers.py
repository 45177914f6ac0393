"""Containers as people name them: recognised by category or by name / metadata name / caption keywords
([containers] config), stored in the catalog (migration 0002), shown by `catalog show`, set by review
(which outranks the rules), drawn by the sampler from the stored flag; compose warns once when a split
has none and names the config keys."""

from __future__ import annotations

import json

import trimesh
from sqlalchemy import select

from mixcount.catalog.containers import ContainerRules, refresh_containers, rule_reason
from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CaptionSet, CatalogObject
from mixcount.cli import main
from mixcount.config import load_config
from mixcount.run.compose import compose_scenes
from mixcount.scene.object_records import ObjectRecord, fallback_captions
from mixcount.scene.sampler import container_warning, sample_scene


def test_rules_by_category_name_and_caption():
    rules = ContainerRules.from_config(load_config([]))
    assert rule_reason(rules, category="plate", texts=[]) == "category 'plate' is in containers.categories"
    assert rule_reason(rules, category="dinner plates", texts=[]).startswith("category 'dinner plate'")
    assert "'platter'" in rule_reason(rules, category="kitchenware", texts=[("name", "Serving_Platter_02")])
    assert "'bowl'" in rule_reason(rules, category="kitchenware", texts=[("caption", "two nested Bowls")])
    for category, name in (("mug", "Coffee Mug"), ("kitchenware", "Plated spoon"), ("toy", "Platypus")):
        assert rule_reason(rules, category=category, texts=[("name", name)]) is None, name
    custom = ContainerRules.from_config(load_config([], ["containers.keywords=['board']", "containers.categories=[]"]))
    assert rule_reason(custom, category="plate", texts=[("name", "cutting board")]).endswith("(containers.keywords)")


def kitchen_library(root):
    """Coarse categories ("Kitchenware") as in the issue: only names say which are containers."""
    for folder, name in (("a", "Wooden Serving Platter"), ("b", "Ceramic Mug"), ("c", "Enamel Dish"),
                         ("d", "Steel Whisk"), ("e", "Glass Jar")):
        path = root / folder
        path.mkdir(parents=True)
        trimesh.creation.box(extents=(0.2, 0.15, 0.03)).export(path / "model.glb")
        (path / "metadata.json").write_text(json.dumps({"name": name, "category": "Kitchenware"}))
    return root


def by_name(catalog):
    with catalog.session() as s:
        return {o.name: o for o in s.scalars(select(CatalogObject))}


def test_ingest_stores_containers_show_prints_them_review_sets_them(tmp_path, catalog, capsys):
    lib = kitchen_library(tmp_path / "kitchen")
    summary = ingest_paths(catalog, [lib], config=load_config([], ["ingest.workers=1"]))
    assert summary.containers == 2
    objs = by_name(catalog)
    assert {n for n, o in objs.items() if o.container} == {"Wooden Serving Platter", "Enamel Dish"}
    assert "'platter' (containers.keywords)" in objs["Wooden Serving Platter"].container_reason
    assert objs["Ceramic Mug"].container_reason is None

    db = str(tmp_path / "catalog.db")
    assert main(["--db", db, "catalog", "show", str(objs["Enamel Dish"].id), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["container"] is True and "dish" in shown["container_reason"] and shown["layout"] == "folder"
    assert main(["--db", db, "catalog", "show", str(objs["Enamel Dish"].id)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.split()[:2] == ["container", "True"] for line in lines)

    # a caption that names a container makes one; a review outranks both rules and captions
    with catalog.session() as s:
        s.add(CaptionSet(object_id=objs["Glass Jar"].id, captioner="stub", provider="stub", model="stub",
                         prompt_version="t", short="tray", concise="a glass tray", detailed="a glass tray",
                         response_hash="0", active=True))
        s.commit()
        refresh_containers(s, load_config([]))
    assert by_name(catalog)["Glass Jar"].container
    decisions = {"format": "mixcount-review-v1", "reviewer": "ana", "decisions": [
        {"id": objs["Enamel Dish"].id, "name": "Enamel Dish", "container": False, "decided_at": "2026-12-01T10:00:00Z"},
        {"id": objs["Steel Whisk"].id, "container": True, "decision": "accept", "decided_at": "2026-12-01T10:00:01Z"},
    ]}
    path = tmp_path / "decisions.json"
    path.write_text(json.dumps(decisions))
    assert main(["--db", db, "catalog", "review", "import", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert sorted(c["container"] for c in out["container_changes"]) == [False, True]
    # the next ingest recomputes from the rules, but the review stays in charge
    ingest_paths(catalog, [lib], config=load_config([], ["ingest.workers=1"]))
    objs = by_name(catalog)
    assert not objs["Enamel Dish"].container and objs["Enamel Dish"].container_reason.startswith("review: not_container by ana")
    assert objs["Steel Whisk"].container and objs["Steel Whisk"].status == "active"
    # a decision that is neither accept/reject nor a container setting is refused, nothing applied
    path.write_text(json.dumps({"format": "mixcount-review-v1", "decisions": [{"id": objs["Ceramic Mug"].id}]}))
    assert main(["--db", db, "catalog", "review", "import", str(path)]) != 0
    assert "neither a decision nor a container setting" in capsys.readouterr().err


def record(oid, category, split, container=False):
    dims = (0.25, 0.2, 0.03) if container else (0.05, 0.05, 0.05)
    return ObjectRecord(oid, f"{category} {oid}", category, dims, fallback_captions(f"{category} {oid}", category),
                        split, f"/lib/{oid}.glb", f"h{oid}", container=container)


def test_sampler_draws_stored_containers_and_warns_per_split(tmp_path):
    cfg = load_config([])
    sconf = cfg.scene
    pool = [record(k, f"thing{k % 3}", "train") for k in range(1, 9)]
    pool += [record(20, "kitchenware", "train", container=True), record(21, "plate", "val")]  # a plate not marked
    drawn = {s.container.object_id for s in (sample_scene(seed, "train", cfg, pool) for seed in range(40)) if s.container}
    assert drawn == {20}  # by the stored flag, not by the category name
    assert container_warning(pool, "train", sconf) is None
    val_pool = pool + [record(30, "thing0", "val")]
    warning = container_warning(val_pool, "val", sconf)
    assert "no container in split 'val'" in warning and "containers.keywords" in warning
    assert "from other splits (1 there, scene.container_other_split_fallback)" in warning
    no_fallback = load_config([], ["scene.container_other_split_fallback=false"]).scene
    assert "scenes get no container" in container_warning(val_pool, "val", no_fallback)


class Notes:
    def __init__(self):
        self.notes = []

    def start(self, label, total): pass

    def advance(self, n=1, *, info=None): pass

    def update(self, *, completed=None, info=None): pass

    def note(self, message):
        self.notes.append(message)

    def stop(self): pass


def test_compose_warns_once_for_a_split_without_containers(tmp_path, capsys):
    pool = [record(k, f"thing{k % 3}", "train") for k in range(1, 9)]
    notes = Notes()
    summary = compose_scenes(pool=pool, config=load_config(["configs/quick.toml"], ["compose.split=train"]),
                             out_dir=tmp_path / "out",
                             assets_dir=tmp_path / "assets", n=0, progress=notes)
    container = [w for w in summary.warnings if "container" in w and "never captioned" not in w
                 and "canonical render" not in w]  # the pool's records were never captioned or rendered: said too
    assert len(container) == 1 and notes.notes == summary.warnings
    assert "no container in split 'train'" in container[0] and "containers.categories" in container[0]
