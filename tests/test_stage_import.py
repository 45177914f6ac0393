"""Composed stages open where users open them (issue 60): Blender 5.0's own ``bpy.ops.wm.usd_import`` and
usd-core's validators, on stages of capture-like objects whose source meshes carry degenerate faces.

The library (tests/degenerate_library.py): real scans with welded (repeated-vertex) and zero-area
triangles as GLB, and public models that carry such faces themselves (assimp's box_longline.obj,
pybullet's lidar), ingested for real. Before this issue Blender segfaulted importing 4 of 6 such
stages (docs/usd.md). Each import runs in its own Python process (a segfault must fail the test, not
end the session); the validators run in a usd-core-only process as tests/test_usd_stage.py does."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mixcount.config import load_config

IMPORT = r"""
import bpy, sys
bpy.ops.wm.read_factory_settings(use_empty=True)
result = bpy.ops.wm.usd_import(filepath=sys.argv[1])
meshes = [o for o in bpy.data.objects if o.type == "MESH"]
print("IMPORTED", sorted(result)[0], len(meshes), sum(len(o.data.polygons) for o in meshes))
"""

VALIDATE = r"""
import json, sys
sys.modules["mixcount"] = None  # only usd-core in this process
from pxr import Usd, UsdGeom, UsdValidation
stage = Usd.Stage.Open(sys.argv[1])
registry = UsdValidation.ValidationRegistry()
validators = [registry.GetOrLoadValidatorByName(m.name) for m in registry.GetAllValidatorMetadata()
              if not m.isSuite and "UsdzValidators" not in m.GetKeywords()]
errors = [f"{e.GetName()}: {e.GetMessage()}" for e in UsdValidation.ValidationContext(validators).Validate(stage)
          if e.GetType() == UsdValidation.ValidationErrorType.Error]
bad = 0
for prim in stage.Traverse():  # Blender's rule: no face may name a vertex twice or one that is not there
    if prim.IsA(UsdGeom.Mesh):
        m = UsdGeom.Mesh(prim)
        counts, idx, n = m.GetFaceVertexCountsAttr().Get(), m.GetFaceVertexIndicesAttr().Get(), len(m.GetPointsAttr().Get())
        k = 0
        for c in counts:
            ring = list(idx[k:k + c]); k += c
            bad += c < 3 or len(set(ring)) != c or min(ring) < 0 or max(ring) >= n
print(json.dumps({"errors": errors, "bad_faces": bad}))
"""


@pytest.fixture(scope="module")
def stages(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], dict[str, int], Path]:
    """Two composed stages (every object of the library in the pool), the expected bad faces per model
    and the catalog's converted assets folder."""
    from degenerate_library import write_library

    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.models import CatalogObject, Split
    from mixcount.catalog.pool_loader import load_pool
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import write_stage

    root = tmp_path_factory.mktemp("degenerate")
    expected, _why = write_library(root / "lib", only=("public_box_longline", "public_hokuyo"))
    cat = open_catalog(f"sqlite:///{root / 'catalog.db'}", data_dir="")
    ingest_paths(cat, [root / "lib"], config=load_config(["quick"], ["ingest.workers=1"]))
    with cat.session() as session:
        for obj in session.query(CatalogObject).filter_by(status="active"):
            session.add(Split(object_id=obj.id, split="train", method="random"))
        session.commit()
        pool = load_pool(session, split="train")
    conf = load_config(["quick"], ["scene.n_objects=[10,14]"])
    paths = [write_stage(sample_scene(seed, "train", conf, pool), root / "out", cat) for seed in (1, 2)]
    cat.close()
    return paths, expected, root / "usd_assets"


@pytest.mark.blender
@pytest.mark.slow
def test_composed_stages_import_in_blender_and_validate(stages: tuple[list[Path], dict[str, int], Path]) -> None:
    paths, expected, _assets = stages
    for path in paths:
        proc = subprocess.run([sys.executable, "-c", IMPORT, str(path)], capture_output=True, text=True, timeout=300)
        text = proc.stdout + proc.stderr
        assert proc.returncode == 0, (path.parent.name, proc.returncode, text[-2000:])  # -11: the segfault
        assert "Invalid face data" not in text, text[-2000:]
        line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("IMPORTED"))
        assert line.split()[1] == "FINISHED" and int(line.split()[2]) > 5
        check = subprocess.run([sys.executable, "-I", "-c", VALIDATE, str(path)], capture_output=True, text=True,
                               timeout=120)
        assert check.returncode == 0, check.stderr[-2000:]
        info = json.loads(check.stdout)
        assert info == {"errors": [], "bad_faces": 0}, info


@pytest.mark.slow
def test_each_asset_record_says_what_was_dropped(stages: tuple[list[Path], dict[str, int], Path]) -> None:
    from degenerate_library import SLIVERS, WELDS
    from pxr import Sdf

    _paths, expected, assets = stages
    records = {}
    for layer_path in sorted(assets.rglob("*.usdc")):
        if layer_path.name.endswith("_collision.usdc"):
            continue
        data = dict(Sdf.Layer.FindOrOpen(str(layer_path)).customLayerData["mixcount"])
        records[Path(data["source"]).parent.name] = dict(data.get("faces_removed", {}))
    for name, bad in expected.items():
        if name not in records:
            continue  # not active in the catalog (size or mesh checks), so never converted
        assert sum(records[name].values()) == bad, (name, records[name])
    welded = [r for n, r in records.items() if n.startswith("welded_")]
    assert welded and all(r == {"repeated_vertex": WELDS, "zero_area": SLIVERS} for r in welded), records
    assert sum(expected[n] for n in records) > WELDS  # the stages hold assets that had such faces
