"""The generated demo library: DTC layout, variety, real-world sizes, textures, traps, determinism."""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh

from mixcount.catalog.ingest import DTC_NAME
from mixcount.demo.library import CONTAINER_CATEGORIES, REPUBLISHED_KINDS, generate_demo_library

REPUBLISHED_SCALED = ("remeshed", "rebaked", "split")  # turned and rescaled x0.5-2 as well


def tree_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


def glb_json(path: Path) -> dict:
    data = path.read_bytes()
    n = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + n])


def down_ray_hits(mesh: trimesh.Trimesh, x: float, y: float) -> list[float]:
    """Heights where a vertical line through (x, y) crosses the mesh (barycentric test per triangle)."""
    tri = mesh.triangles
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
    p = np.array([x, y]) - a[:, :2]
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    ok = np.abs(den) > 1e-15
    den = np.where(ok, den, 1.0)
    u = (p[:, 0] * v1[:, 1] - v1[:, 0] * p[:, 1]) / den
    v = (v0[:, 0] * p[:, 1] - p[:, 0] * v0[:, 1]) / den
    inside = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
    z = a[:, 2] + u * (b[:, 2] - a[:, 2]) + v * (c[:, 2] - a[:, 2])
    return z[inside].tolist()


def test_full_library_layout_variety_and_traps(tmp_path):
    root = tmp_path / "demo"
    truth = generate_demo_library(root, seed=0)
    on_disk = json.loads((root / "ground_truth.json").read_text())
    assert on_disk == json.loads(json.dumps(truth))
    objects = truth["objects"]
    folders = {p.name for p in root.iterdir() if p.is_dir()}
    assert folders == {o["folder"] for o in objects}
    ordinary = [o for o in objects if o["kind"] == "object"]
    containers = [o for o in objects if o["container"]]
    assert len(ordinary) >= 48
    assert len({o["category"] for o in ordinary}) >= 10
    assert {o["category"] for o in containers} == set(CONTAINER_CATEGORIES)
    for o in objects:
        folder = root / o["folder"]
        meta = json.loads((folder / "metadata.json").read_text())
        assert meta["category"] == o["category"]
        if o["source"] == "folder":  # another name and source: a plain folder with an OBJ in centimetres
            assert o["kind"] in ("other_source", "units") and "up_axis" not in meta
            assert meta.get("units") == ("cm" if o["kind"] == "other_source" else None)  # units: cm, undeclared
            assert {p.name for p in folder.iterdir()} >= {"mesh.obj", "mesh.mtl", "texture_0.png", "metadata.json", "LICENSE"}
            continue
        assert DTC_NAME.match(o["folder"]), o["folder"]
        assert {p.name for p in folder.iterdir()} == {"3d-asset.glb", "metadata.json", "LICENSE", "preview.png"}
        assert o["model"] == f"{o['folder']}/3d-asset.glb"
        if o["kind"] == "broken":
            continue
        size = max(o["dims_m"])
        if o["container"]:
            assert 0.20 <= max(o["dims_m"][:2]) <= 0.35 and o["dims_m"][2] < 0.1, o
        elif o["kind"] not in ("rescale", "turned", "units") + REPUBLISHED_SCALED:
            assert 0.02 <= size <= 0.25, o
        doc = glb_json(folder / "3d-asset.glb")
        assert doc["materials"], o["folder"]
        for mat in doc["materials"]:
            pbr = mat["pbrMetallicRoughness"]
            assert "roughnessFactor" in pbr and "metallicFactor" in pbr
        prims = [p for m in doc["meshes"] for p in m["primitives"]]
        has_image = "images" in doc and any("baseColorTexture" in m["pbrMetallicRoughness"] for m in doc["materials"])
        assert (o["appearance"] == "image") == has_image
        if o["appearance"] == "vertex_color":
            assert all("COLOR_0" in p["attributes"] for p in prims)
    image = sum(o["appearance"] == "image" for o in objects if o["kind"] != "broken")
    assert image >= len(objects) / 2
    # real variety: sizes span an order of magnitude, and the shapes differ (face counts, extents)
    sizes = [max(o["dims_m"]) for o in ordinary]
    assert max(sizes) / min(sizes) > 5
    assert len({tuple(np.round(o["dims_m"], 3)) for o in ordinary}) >= 40
    # containers are open on top: a ray straight down at the centre hits the inner floor low down
    for o in containers:
        mesh = trimesh.load(root / o["folder"] / "3d-asset.glb", force="mesh")
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # Y-up -> Z-up
        top = mesh.bounds[1][2]
        centre = mesh.bounds.mean(axis=0)
        hits = down_ray_hits(mesh, centre[0], centre[1])
        assert len(hits) and max(hits) < top - 0.004, o["folder"]
    # traps
    assert len(truth["exact_copies"]) == len(truth["recolours"]) == len(truth["rescales"]) == 2
    for a, b in truth["exact_copies"]:
        assert (root / a / "3d-asset.glb").read_bytes() == (root / b / "3d-asset.glb").read_bytes()
    for a, b in truth["recolours"]:
        assert (root / a / "3d-asset.glb").read_bytes() != (root / b / "3d-asset.glb").read_bytes()
    by = {o["folder"]: o for o in objects}
    for a, b, factor in truth["rescales"]:
        assert np.allclose(np.array(by[b]["dims_m"]), factor * np.array(by[a]["dims_m"]), atol=1e-5)

    def loaded(entry) -> trimesh.Trimesh:
        return trimesh.load(root / entry["model"], force="mesh")

    def moments(mesh) -> np.ndarray:
        v = mesh.vertices - mesh.vertices.mean(axis=0)
        return np.sort(np.linalg.eigvalsh(v.T @ v / len(v)))

    assert len(truth["turned_rescales"]) == len(truth["retessellated"]) == len(truth["other_source"]) == 2
    for a, b, factor in truth["turned_rescales"]:  # turned over: other extents, same shape at factor x
        ma, mb = loaded(by[a]), loaded(by[b])
        assert np.allclose(moments(mb), factor ** 2 * moments(ma), rtol=1e-6)
        assert len(ma.vertices) == len(mb.vertices)
        assert not np.allclose(mb.vertices - mb.vertices.mean(axis=0), factor * (ma.vertices - ma.vertices.mean(axis=0)),
                               atol=1e-4)  # turned, not only scaled
    for a, b in truth["retessellated"]:  # every triangle split in four, the same surface
        ma, mb = loaded(by[a]), loaded(by[b])
        assert len(mb.faces) == 4 * len(ma.faces) and mb.area == pytest.approx(ma.area, rel=1e-6)  # float32 GLB
        assert np.allclose(by[a]["dims_m"], by[b]["dims_m"], atol=1e-6)
    for a, b in truth["other_source"]:  # OBJ in cm, 1.25x: area scales by 1.25^2 and 100^2
        ma, mb = loaded(by[a]), loaded(by[b])
        assert mb.area == pytest.approx(ma.area * 1.25 ** 2 * 1e4, rel=1e-4)
    # copies rebuilt from the surface: each kind twice, none sharing the original's mesh data
    republished = {"remeshed": "remeshed", "unit_changes": "units", "rebaked": "rebaked", "split_parts": "split"}
    assert set(republished.values()) == set(REPUBLISHED_KINDS)
    originals = {e[0] for key in ("exact_copies", "recolours", "rescales", "turned_rescales", "retessellated",
                                  "other_source") for e in truth[key]}
    for key, kind in republished.items():
        assert len(truth[key]) == 2, key
        for a, b, factor in truth[key]:
            assert a in originals and by[b]["kind"] == kind and by[b]["of"] == a  # clean objects stay the same set
            ma, mb = loaded(by[a]), loaded(by[b])
            original = {tuple(x) for x in np.round(ma.vertices * factor, 5)}
            shared = sum(tuple(x) in original for x in np.round(mb.vertices, 5))
            assert shared < 0.05 * len(mb.vertices), (key, b)  # turned (and remeshed): no vertex of the original
            doc = glb_json(root / b / "3d-asset.glb") if by[b]["source"] == "dtc" else None
            if doc is not None:
                assert "images" in doc and len(doc["meshes"]) == by[b]["n_parts"]
            if kind == "remeshed":
                ratio = len(mb.faces) / len(ma.faces)
                assert ratio > 2.5 or ratio <= 0.5, (b, ratio)  # a very different face count
            if kind == "units":
                assert factor in (100.0, 1000.0)
                assert mb.area == pytest.approx(ma.area * factor ** 2, rel=0.1)
            elif kind == "split":
                assert by[b]["n_parts"] == by[b]["parts"] in (3, 5)
            else:
                assert mb.area == pytest.approx(ma.area * factor ** 2, rel=0.1)
            if kind == "rebaked":
                assert len(mb.faces) == len(ma.faces) and by[b]["gain"] in (1.0, 0.88)
    (tote,) = truth["mesh_quality"]
    from mixcount.catalog.mesh import load_normalised
    from mixcount.curation.finding.descriptors import boundary_fraction, nonmanifold_fraction

    mesh = load_normalised(root / by[tote]["model"]).mesh
    assert nonmanifold_fraction(mesh.faces) > 0.05 and boundary_fraction(mesh.faces) > 0
    assert len(truth["broken"]) >= 2
    kinds = {b["expected_error"] for b in truth["broken"]}
    assert kinds == {"truncated GLB", "not a GLB file"}
    assert truth["expected"]["total"] == len(objects)
    assert truth["expected"]["broken"] == len(truth["broken"])


def test_same_seed_same_bytes_and_small_libraries(tmp_path):
    a = generate_demo_library(tmp_path / "a", seed=7, n_objects=8)
    b = generate_demo_library(tmp_path / "b", seed=7, n_objects=8)
    assert a == b
    assert tree_digest(tmp_path / "a") == tree_digest(tmp_path / "b")
    generate_demo_library(tmp_path / "c", seed=8, n_objects=8)
    assert tree_digest(tmp_path / "c") != tree_digest(tmp_path / "a")
    ordinary = [o for o in a["objects"] if o["kind"] == "object"]
    assert len(ordinary) == 8 and len({o["category"] for o in ordinary}) == 8  # round-robin over categories
    assert a["exact_copies"] and a["recolours"] and a["rescales"] and len(a["broken"]) == 2
    assert a["containers"]
    # regenerating into the same folder replaces the library instead of adding to it
    generate_demo_library(tmp_path / "a", seed=9, n_objects=4)
    assert len([p for p in (tmp_path / "a").iterdir() if p.is_dir()]) == json.loads(
        (tmp_path / "a" / "ground_truth.json").read_text())["expected"]["total"]
