"""Scene stages: a demo scene opens in a fresh process with only usd-core, passes USD's validators,
has the spec's counted prims per class, physics and lights; same seed -> byte-identical scene.usda."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mixcount.catalog.pool_loader import load_pool
from mixcount.config import load_config
from mixcount.scene.sampler import sample_scene
from mixcount.usd.stage import write_stage

CHILD = r"""
import json, sys
sys.modules["mixcount"] = None  # only usd-core in this process
from pxr import Usd, UsdGeom, UsdLux, UsdPhysics, UsdShade, UsdUtils, UsdValidation

path = sys.argv[1]
stage = Usd.Stage.Open(path)
registry = UsdValidation.ValidationRegistry()
validators = [registry.GetOrLoadValidatorByName(m.name) for m in registry.GetAllValidatorMetadata()
              if not m.isSuite and "UsdzValidators" not in m.GetKeywords()]
findings = UsdValidation.ValidationContext(validators).Validate(stage)
errors = [f"{e.GetName()}: {e.GetMessage()}" for e in findings
          if e.GetType() == UsdValidation.ValidationErrorType.Error]
try:
    from pxr.UsdUtils.complianceChecker import ComplianceChecker
    checker = ComplianceChecker(arkit=False, skipARKitRootLayerCheck=True)
    checker.CheckCompliance(path)
    errors += list(checker.GetErrors())
    compliance = "ComplianceChecker+UsdValidation"
except ImportError:
    compliance = "UsdValidation"
layers, assets, unresolved = UsdUtils.ComputeAllDependencies(path)
counts, roles, physics, ids = {}, {}, [], []
for prim in stage.Traverse():
    role = prim.GetCustomDataByKey("mixcount:role")
    if role is None:
        continue
    roles[role] = roles.get(role, 0) + 1
    ids.append(prim.GetCustomDataByKey("mixcount:instance_id"))
    assert prim.GetAttribute("userProperties:mixcount:instance_id").Get() == ids[-1]  # for Blender
    assert prim.GetAttribute("userProperties:mixcount:role").Get() == role
    if role == "counted":
        ci = prim.GetCustomDataByKey("mixcount:class_index")
        counts[str(ci)] = counts.get(str(ci), 0) + 1
    if role in ("counted", "distractor"):
        meshes = [p for p in Usd.PrimRange(prim) if p.IsA(UsdGeom.Mesh)]
        # the collider: the asset's convex proxy (a guide child) when the catalog has one, else the prim
        proxy = stage.GetPrimAtPath(prim.GetPath().AppendChild("Proxy"))
        collider = proxy if proxy and UsdPhysics.CollisionAPI(proxy).GetCollisionEnabledAttr().Get() else prim
        physics.append(bool(meshes) and prim.HasAPI(UsdPhysics.RigidBodyAPI)
                       and collider.HasAPI(UsdPhysics.CollisionAPI)
                       and UsdPhysics.MeshCollisionAPI(collider).GetApproximationAttr().Get() == "convexHull"
                       and (collider == prim or UsdGeom.Imageable(proxy).ComputePurpose() == "guide"))
container = stage.GetPrimAtPath("/World/Container")
coll = stage.GetPrimAtPath("/World/Container/Collision")
cams = [UsdGeom.Camera(p) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
dome = [p for p in stage.Traverse() if p.IsA(UsdLux.DomeLight)]
floor = stage.GetPrimAtPath("/World/Floor")
mat = UsdShade.MaterialBindingAPI(floor).ComputeBoundMaterial()[0]
print(json.dumps({
    "compliance": compliance, "errors": errors, "unresolved": list(unresolved),
    "n_textures": sum(1 for a in assets if a.endswith(".png")),
    "counts": counts, "roles": roles, "physics_ok": all(physics), "ids": ids,
    "meta": {k: v for k, v in stage.GetRootLayer().customLayerData["mixcount"].items() if k != "spec"},
    "spec": stage.GetRootLayer().customLayerData["mixcount"]["spec"],
    "mpu": UsdGeom.GetStageMetersPerUnit(stage), "up": UsdGeom.GetStageUpAxis(stage),
    "default_prim": str(stage.GetDefaultPrim().GetPath()),
    "physics_scene": any(p.IsA(UsdPhysics.Scene) for p in stage.Traverse()),
    "container_collider": bool(coll) and coll.HasAPI(UsdPhysics.CollisionAPI)
        and UsdPhysics.MeshCollisionAPI(coll).GetApproximationAttr().Get() == "none"
        and UsdGeom.Imageable(coll).GetPurposeAttr().Get() == "guide"
        and not container.HasAPI(UsdPhysics.RigidBodyAPI),
    "floor_collider": floor.HasAPI(UsdPhysics.CollisionAPI) and not floor.HasAPI(UsdPhysics.RigidBodyAPI),
    "floor_material": bool(mat),
    "camera": [c.GetFocalLengthAttr().Get() for c in cams] + [c.GetHorizontalApertureAttr().Get() for c in cams],
    "dome": len(dome),
}))
"""


def build_demo_catalog(root: Path, n_objects: int = 16):
    """Demo library -> real ingest -> every active object in train. Returns the open catalog."""
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.models import CatalogObject, Split
    from mixcount.demo.library import generate_demo_library

    generate_demo_library(root / "lib", seed=0, n_objects=n_objects)
    cat = open_catalog(f"sqlite:///{root / 'catalog.db'}", data_dir="")
    ingest_paths(cat, [root / "lib"], config=load_config(["quick"], ["ingest.workers=1"]))
    with cat.session() as session:
        for obj in session.query(CatalogObject).filter_by(status="active").order_by(CatalogObject.id):
            session.add(Split(object_id=obj.id, split="train", method="random"))
        session.commit()
    return cat


@pytest.fixture(scope="module")
def demo(tmp_path_factory, demo_catalog_copy):
    from mixcount.catalog.db import open_catalog

    root = demo_catalog_copy(tmp_path_factory.mktemp("demo_scene"), 16)  # build_demo_catalog(root), copied
    cat = open_catalog(f"sqlite:///{root / 'catalog.db'}", data_dir="")
    with cat.session() as session:
        pool = load_pool(session, split="train")
    conf = load_config(["quick"], ["scene.no_container_probability=0.0"])
    yield root, cat, pool, conf
    cat.close()


def run_child(stage_path: Path) -> dict:
    proc = subprocess.run([sys.executable, "-I", "-c", CHILD, str(stage_path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def test_demo_stage_opens_clean_in_fresh_usd_process(demo):
    root, cat, pool, conf = demo
    spec = sample_scene(7, "train", conf, pool)
    assert spec.container is not None and spec.distractors
    path = write_stage(spec, root / "out", cat)
    assert path == root / "out" / "scenes" / "scene_000007" / "scene.usda"
    info = run_child(path)
    assert info["errors"] == [], info["errors"]
    assert info["unresolved"] == []
    assert info["n_textures"] >= 2  # textured demo assets + the procedural floor
    assert info["counts"] == {str(k): v for k, v in spec.counts_per_class().items()}
    assert info["roles"] == {"counted": spec.n_counted, "distractor": len(spec.distractors), "container": 1, "floor": 1}
    assert sorted(info["ids"]) == list(range(0, spec.n_counted + len(spec.distractors) + 2))
    assert info["physics_ok"] and info["physics_scene"] and info["container_collider"] and info["floor_collider"]
    assert info["floor_material"] and info["dome"] == 1
    assert info["meta"] == {"scene_id": "scene_000007", "seed": 7, "config_hash": conf.hash, "split": "train"}
    # the spec as recorded: no absolute path (catalog assets as assets/<name>, source files by name)
    from mixcount.usd.portable import PathRoots, portable_paths

    assert json.loads(info["spec"]) == portable_paths(spec.to_dict(), PathRoots(root / "out", (Path(cat.usd_assets_dir),)))
    assert all(a["model_path"].startswith("source:") for a in json.loads(info["spec"])["assets"])
    assert "/" + str(root).strip("/").split("/")[0] not in path.read_text()  # no path of this machine
    assert info["mpu"] == 1.0 and info["up"] == "Z" and info["default_prim"] == "/World"
    assert info["camera"] == pytest.approx([conf.scene.focal_length_mm, conf.scene.sensor_width_mm])  # millimetres
    classes = json.loads(info["spec"])["classes"]
    for c in classes:
        assert set(c["captions"]) == {"short", "concise", "detailed"}
        if c["size_qualifier"]:
            for text in c["captions"].values():
                assert c["size_qualifier"] in text.lower().split()


def test_same_seed_byte_identical_different_seed_different(demo):
    root, cat, pool, conf = demo
    a = write_stage(sample_scene(21, "train", conf, pool), root / "out_a", cat)
    b = write_stage(sample_scene(21, "train", conf, pool), root / "out_b", cat)
    c = write_stage(sample_scene(22, "train", conf, pool), root / "out_a", cat)
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    floor_a = sorted((a.parent / "textures").iterdir())
    floor_b = sorted((b.parent / "textures").iterdir())
    assert [p.read_bytes() for p in floor_a] == [p.read_bytes() for p in floor_b]


def test_stage_without_container_and_with_hdri(demo, tmp_path):
    from pxr import Usd, UsdLux
    from test_scene_environments import write_hdr

    from mixcount.scene.object_records import EnvironmentRecord

    root, cat, pool, _conf = demo
    hdr = write_hdr(tmp_path / "sky.hdr")
    conf = load_config(["quick"], ["scene.no_container_probability=1.0"])
    spec = sample_scene(3, "train", conf, pool, environments=[EnvironmentRecord(1, "sky", str(hdr), "h")])
    path = write_stage(spec, tmp_path / "out", cat)
    info = run_child(path)
    assert info["errors"] == [] and info["unresolved"] == []
    assert info["roles"].get("container") is None
    stage = Usd.Stage.Open(str(path))
    dome = UsdLux.DomeLight(stage.GetPrimAtPath("/World/Lights/Dome"))
    texture = dome.GetTextureFileAttr().Get()
    assert texture.path == "../../assets/environments/sky.hdr"  # relative: the dataset's entry
    assert Path(texture.resolvedPath).resolve() == hdr.resolve()  # a link to the catalog's map until packaged
    assert not stage.GetPrimAtPath("/World/Lights/Sun")  # the sun belongs to the procedural sky only
