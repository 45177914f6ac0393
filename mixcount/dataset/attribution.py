"""ATTRIBUTION.json / ATTRIBUTION.md: every catalog object a dataset shows, with its source and licence.

A dataset cannot be shared without this: DTC models come under a CC BY-SA variant and the MixCount
dataset itself is CC BY-SA. Everything is read from the dataset folder alone: each finished scene's
``metadata.json`` holds the scene spec, whose ``assets`` list every catalog object the scene used with
``source`` (dtc | folder), ``source_id`` (the stable key there), ``license`` (the licence text found at
ingest) and ``content_hash``; the spec's classes, distractors and container give each object's role.
Environment maps and floor materials are listed too: bpy's bundled HDRIs (the default light) with the
licence, author and original named in the ``license.txt`` beside them; the catalog records no licence
for ingested maps and materials.

Identical licence texts are stored once (``licenses``, keyed by the SHA-256 of the text) and objects
refer to them by ``license_id``. Objects without a recorded licence are listed under
``missing_license``; a scene composed before provenance was recorded lacks ``source`` as well.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional

from mixcount.dataset.scene_writer import is_complete

JSON_NAME = "ATTRIBUTION.json"
MD_NAME = "ATTRIBUTION.md"
DATASET_LICENSE_NOTE = (
    "The MixCount paper publishes its dataset under CC BY-SA; DTC object models are licensed under a "
    "variant of CC BY-SA (Digital Twin Catalog Dataset License Agreement). Check every licence below "
    "before sharing this dataset."
)


def _scene_dirs(dataset_root: Path, scene_ids: Optional[Iterable[str]]) -> list[Path]:
    scenes = Path(dataset_root) / "scenes"
    if not scenes.is_dir():
        return []
    if scene_ids is not None:
        wanted = sorted(set(scene_ids))
        return [scenes / s for s in wanted if is_complete(scenes / s)]
    return sorted(d for d in scenes.iterdir() if d.is_dir() and not d.name.startswith(".") and is_complete(d))


def _license_id(text: str) -> str:
    return "sha256:" + hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def attribution_extract(spec: Mapping[str, Any]) -> dict[str, Any]:
    """What attribution needs of one scene spec, small enough for the merge index (no licence texts):
    each object's roles, the environment map and the floor material."""
    roles: dict[int, set[str]] = {}
    for c in spec.get("classes", []):
        roles.setdefault(int(c["object_id"]), set()).add("counted")
    for o in spec.get("distractors", []):
        roles.setdefault(int(o["object_id"]), set()).add("distractor")
    if spec.get("container"):
        roles.setdefault(int(spec["container"]["object_id"]), set()).add("container")
    for a in spec.get("assets", []):
        roles.setdefault(int(a["object_id"]), set())
    env = spec.get("environment") or {}
    mat = (spec.get("floor") or {}).get("material") or {}
    return {
        "roles": {str(k): sorted(v) for k, v in sorted(roles.items())},
        "environment": ({"kind": env.get("kind"), "environment_id": env.get("environment_id"), "path": env["path"]}
                        if env.get("path") else None),
        "material": ({"name": mat.get("name"), "material_id": mat.get("material_id"), "maps": mat.get("maps") or {}}
                     if mat.get("kind") == "pbr" or mat.get("material_id") is not None else None),
    }


def environment_license(path: str) -> dict[str, Any]:
    """Licence fields of an environment map: for one of bpy's bundled HDRIs the ``license.txt`` beside
    it gives ``source`` "bpy_bundled", ``license`` (CC0), ``author``, ``provider`` (Poly Haven),
    ``provider_url``, ``original_url`` (the Poly Haven page of the original; ``original_uncertain`` when
    the text says "Probably") and ``license_text``; an ingested map gets nothing (no licence recorded)."""
    from mixcount.scene.bundled_environments import BUNDLED_SOURCE, bundled_license, is_bundled_path

    if not is_bundled_path(path):
        return {}
    info = bundled_license(path)
    if info is None:
        return {"source": BUNDLED_SOURCE}
    return {"source": BUNDLED_SOURCE, "name": info["name"], "license": info["license"], "author": info["author"],
            "provider": info["source"], "provider_url": info["source_url"], "original_url": info["original_url"],
            "original_uncertain": info["original_uncertain"], "license_text": info["license_text"]}


class AttributionCollector:
    """Builds the attribution document one scene at a time (memory grows with the objects, not the scenes).

    ``add(scene_dir, extract, spec)`` takes :func:`attribution_extract` of a scene; an object seen for the
    first time has its source and licence taken from the scene's spec: ``spec`` when the caller has it
    parsed already, else read from the scene's ``metadata.json`` (once per object)."""

    def __init__(self) -> None:
        self.objects: dict[int, dict[str, Any]] = {}
        self.licenses: dict[str, dict[str, Any]] = {}
        self.environments: dict[str, dict[str, Any]] = {}
        self.materials: dict[str, dict[str, Any]] = {}
        self.scenes = 0

    def _assets_of(self, scene_dir: Path) -> dict[int, Mapping[str, Any]]:
        spec = json.loads((Path(scene_dir) / "metadata.json").read_text(encoding="utf-8")).get("spec") or {}
        return {int(a["object_id"]): a for a in spec.get("assets", [])}

    def add(self, scene_dir: Path, extract: Mapping[str, Any], spec: Optional[Mapping[str, Any]] = None) -> None:
        self.scenes += 1
        assets: Optional[dict[int, Mapping[str, Any]]] = None
        if spec is not None:
            assets = {int(a["object_id"]): a for a in spec.get("assets", [])}
        for key, roles in extract.get("roles", {}).items():
            oid = int(key)
            entry = self.objects.get(oid)
            if entry is None:
                if assets is None:
                    assets = self._assets_of(scene_dir)
                a = assets.get(oid, {})
                text = a.get("license")
                lid = None
                if text:
                    lid = _license_id(text)
                    self.licenses.setdefault(lid, {"id": lid, "text": text, "objects": 0})
                    self.licenses[lid]["objects"] += 1
                entry = self.objects[oid] = {
                    "object_id": oid, "name": a.get("name"), "category": a.get("category"),
                    "source": a.get("source"), "source_id": a.get("source_id"), "license_id": lid,
                    "content_hash": a.get("content_hash"), "roles": set(), "scenes": 0,
                }
            entry["roles"] |= set(roles)
            entry["scenes"] += 1
        env = extract.get("environment")
        if env:
            e = self.environments.get(env["path"])
            if e is None:
                e = self.environments[env["path"]] = {**env, "license": None, "scenes": 0, **environment_license(env["path"])}
            e["scenes"] += 1
        mat = extract.get("material")
        if mat:
            m = self.materials.setdefault(str(mat.get("name")), {**mat, "license": None, "scenes": 0})
            m["scenes"] += 1

    def document(self) -> dict[str, Any]:
        obj_list = []
        for oid in sorted(self.objects):
            o = dict(self.objects[oid])
            o["roles"] = sorted(o["roles"])
            obj_list.append(o)
        return {
            "note": DATASET_LICENSE_NOTE,
            "scenes": self.scenes,
            "objects": obj_list,
            "licenses": [self.licenses[k] for k in sorted(self.licenses)],
            "missing_license": [o["object_id"] for o in obj_list if o["license_id"] is None],
            "environments": [self.environments[k] for k in sorted(self.environments)],
            "materials": [self.materials[k] for k in sorted(self.materials)],
        }


def collect_attribution(dataset_root: Path | str, scene_ids: Optional[Iterable[str]] = None) -> dict[str, Any]:
    """The attribution document of the finished scenes of ``dataset_root`` (only ``scene_ids`` when given)."""
    collector = AttributionCollector()
    for d in _scene_dirs(Path(dataset_root), scene_ids):
        spec = json.loads((d / "metadata.json").read_text(encoding="utf-8")).get("spec") or {}
        collector.add(d, attribution_extract(spec), spec)
    return collector.document()


def _cell(value: Any) -> str:
    return "" if value is None else str(value).replace("|", "\\|").replace("\n", " ")


def attribution_markdown(doc: Mapping[str, Any]) -> str:
    """Human-readable ATTRIBUTION.md of :func:`collect_attribution`'s document."""
    lines = ["# Attribution", "", doc["note"], "",
             f"{len(doc['objects'])} catalog object(s) in {doc['scenes']} scene(s).", ""]
    if doc["missing_license"]:
        lines += [(f"**No licence was recorded at ingest for {len(doc['missing_license'])} object(s)** "
                   f"(object ids {', '.join(map(str, doc['missing_license']))}): find their terms before sharing."), ""]
    lines += ["## Objects", "", "| object id | name | category | source | source id | roles | scenes | licence |",
              "|---|---|---|---|---|---|---|---|"]
    short = {lic["id"]: f"L{k + 1}" for k, lic in enumerate(doc["licenses"])}
    for o in doc["objects"]:
        lines.append("| " + " | ".join(_cell(v) for v in (
            o["object_id"], o["name"], o["category"], o["source"] or "(not recorded)", o["source_id"],
            ", ".join(o["roles"]), o["scenes"], short.get(o["license_id"], "none recorded"))) + " |")
    lines += ["", "## Licences", ""]
    for lic in doc["licenses"]:
        lines += [f"### {short[lic['id']]} ({lic['objects']} object(s), {lic['id']})", "", "```", lic["text"], "```", ""]
    if doc["environments"] or doc["materials"]:
        lines += ["## Environment maps and floor materials", "",
                  ("HDRIs bundled with Blender (bpy) carry their licence below. The catalog records no licence "
                   "for ingested maps and materials; check their sources (Poly Haven and similar libraries "
                   "publish CC0 assets)."), ""]
        for e in doc["environments"]:
            if e.get("license"):
                original = e.get("original_url") or "(original not named)"
                if e.get("original_uncertain"):
                    original = f"probably {original}"
                lines.append(f"- environment map `{e['path']}` ({e['scenes']} scene(s)): {e['name']}, bundled with "
                             f"Blender; {e['license']}, by {e['author']} ({e['provider']} {e['provider_url']}); "
                             f"original: {original}")
            else:
                lines.append(f"- environment map `{e['path']}` ({e['scenes']} scene(s))")
        for m in doc["materials"]:
            lines.append(f"- floor material `{m['name']}` ({m['scenes']} scene(s))")
        lines.append("")
    return "\n".join(lines)


def write_attribution_document(doc: Mapping[str, Any], out_dir: Path | str) -> None:
    """Write ``doc`` as ATTRIBUTION.json and ATTRIBUTION.md into ``out_dir`` (atomic renames)."""
    from mixcount.atomic import write_text_atomic

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in ((JSON_NAME, json.dumps(doc, indent=1, ensure_ascii=False) + "\n"),
                       (MD_NAME, attribution_markdown(doc))):
        write_text_atomic(out / name, text)


def write_attribution(dataset_root: Path | str, out_dir: Path | str,
                      scene_ids: Optional[Iterable[str]] = None) -> dict[str, Any]:
    """Write ATTRIBUTION.json and ATTRIBUTION.md of ``dataset_root``'s scenes into ``out_dir``; returns the document."""
    doc = collect_attribution(dataset_root, scene_ids)
    write_attribution_document(doc, out_dir)
    return doc
