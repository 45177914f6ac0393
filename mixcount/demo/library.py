"""A generated demo object library in the Digital Twin Catalog layout, deterministic from a seed.

``generate_demo_library(root, seed=...)`` writes one folder per object, named like DTC's
``Marker_B07Z5P84J2_Peach``, holding ``3d-asset.glb``, ``metadata.json``, ``LICENSE`` and
``preview.png``, plus ``root/ground_truth.json`` describing every folder and the planted traps:

* 58 everyday objects in 15 categories (ball, marker, fruit, block, mug, bottle, die, figurine, can,
  cup, pencil, eraser, coin, cookie, donut), 2-25 cm, built from revolves, boxes and extrusions with
  UVs; about two thirds carry a PNG image texture, the rest vertex colours with PBR factors;
* 6 containers (plate, tray, bowl; 20-35 cm, open on top) for scenes to drop objects into;
* traps for curation: exact copies under another name, the same shape recoloured, the same object
  rescaled, the same object turned over and rescaled, the same object re-tessellated (every triangle
  split in four), the same object under another name from another source (a plain folder holding an OBJ
  in centimetres, 1.25x larger, stored Z-up but undeclared, so it is read lying on its side), broken
  files (a truncated GLB, non-mesh bytes named ``3d-asset.glb``), and a clean object whose mesh is
  non-manifold and open (a tote with a flat strap welded to its rim: usable, a ``mesh_quality`` warning);
* copies as another source publishes a scan, rebuilt from the original's surface rather than its mesh
  data (:mod:`mixcount.demo.traps`), two of each: remeshed (pymeshlab isotropic / quadric decimation),
  stored in other units (mm or cm read as m), texture re-baked into a new atlas, split into parts; each
  also turned, rescaled and with its origin moved (``remeshed``, ``unit_changes``, ``rebaked``,
  ``split_parts`` in the ground truth). They are written after everything else from their own random
  stream, so the older objects keep their names and bytes.

Geometry is built Z-up in metres and stored the glTF way (Y-up): each part's node carries the Z-up ->
Y-up rotation and its placement, so ingest has to apply node transforms to measure it correctly.
``ground_truth.json`` records, per object, its model file (``model``), the layout ingest reads it as
(``source``) and the dimensions ingest should measure (``dims_m``, metres, Z-up as read).

By concern: :mod:`mixcount.demo.geometry` (parts and shapes), :mod:`mixcount.demo.textures`,
:mod:`mixcount.demo.objects` (one builder per category), :mod:`mixcount.demo.writers` (GLB, OBJ, folders),
:mod:`mixcount.demo.traps` (surface-rebuilt copies); this module plants them into one library.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from mixcount.demo.geometry import Part, baked, recolour, rotation_xyz, subdivide
from mixcount.demo.objects import (  # noqa: F401 - the builders are this module's public face too
    BUILDERS,
    CONTAINER_BUILDERS,
    Spec,
    build_ball,
    build_can,
    build_die,
    build_mug,
    build_tote,
)
from mixcount.demo.writers import (  # noqa: F401
    GENERATOR,
    LICENSE_TEXT,
    dtc_id,
    export_glb,
    export_obj,
    preview,
    write_object,
    zup_dims,
)

CONTAINER_CATEGORIES = ("plate", "tray", "bowl")


REPUBLISHED_KINDS = ("remeshed", "units", "rebaked", "split")


def _republished_traps(root: Path, originals: list[tuple[str, Spec, bytes]], n_traps: int, seed: int,
                       emit: Callable[..., str], objects: list[dict[str, Any]]) -> tuple[list[Any], ...]:
    """Copies of ``originals`` rebuilt from their surface only (:mod:`mixcount.demo.traps`), ``n_traps`` of
    each kind, each also turned by a random rotation, rescaled (x0.5-0.8 or x1.25-2, other than ``units``)
    and with its origin moved off the object, as another source would store it:

    * ``remeshed``: pymeshlab isotropic remeshing to ~6x the faces, or quadric decimation to 1/4, texture
      re-baked into a new atlas;
    * ``units``: remeshed and re-baked, then stored in millimetres read as metres (a GLB 1000x the size)
      or in centimetres read as metres (an OBJ in a plain folder declaring no units, 100x, Z-up read as
      Y-up);
    * ``rebaked``: the same surface in a new UV atlas, vertex colours or texture re-baked into 512 texels
      a side, or into 128 and 12 % darker (re-baked under other lighting);
    * ``split``: re-baked and cut into 3 or 5 parts, each with its own origin.

    Returns the four ground-truth lists of ``[original, copy, scale]``."""
    from scipy.spatial.transform import Rotation

    from mixcount.demo import traps as T

    out: dict[str, list[Any]] = {kind: [] for kind in REPUBLISHED_KINDS}
    if not originals:
        return tuple(out.values())
    rng = np.random.default_rng([seed, 5])
    order = [originals[int(i)] for i in rng.permutation(len(originals))]
    for k in range(len(REPUBLISHED_KINDS) * n_traps):
        kind, t = REPUBLISHED_KINDS[k // n_traps], k % n_traps
        name, spec, _ = order[k % len(order)]
        colour = T.surface_colour(spec.parts, seed=seed * 1000 + k)
        vertices, faces = T.weld(spec.parts)
        look = {"roughness": spec.parts[0].roughness, "metallic": spec.parts[0].metallic}
        size = float(np.ptp(vertices, axis=0).max())
        origin = tuple(float(x) for x in rng.uniform(-0.6, 0.6, 3) * size)
        detail: dict[str, Any] = {}
        if kind == "remeshed":
            method = ("isotropic", "decimate")[t % 2]
            target = min(20_000, max(4_000, 6 * len(faces))) if method == "isotropic" else max(60, len(faces) // 4)
            vertices, faces = T.remesh(vertices, faces, method=method, target_faces=target)
            parts = [T.bake(vertices, faces, colour, size=512, **look)]
            detail = {"method": method, "faces": int(len(faces))}
        elif kind == "units":
            method = ("isotropic", "decimate")[t % 2]
            target = max(2_000, 2 * len(faces)) if method == "isotropic" else max(120, len(faces) // 2)
            vertices, faces = T.remesh(vertices, faces, method=method, target_faces=min(20_000, target))
            parts = [T.bake(vertices, faces, colour, size=512, **look)]
            detail = {"method": method, "faces": int(len(faces))}
        elif kind == "rebaked":
            side, gain = ((512, 1.0), (128, 0.88))[t % 2]
            parts = [T.bake(vertices, faces, colour, size=side, gain=gain, **look)]
            detail = {"texture_px": int(parts[0].image.size[0]), "gain": gain}  # type: ignore[union-attr]
        else:
            pieces = (3, 5)[t % 2]
            if t % 2 == 0:
                vertices, faces = T.remesh(vertices, faces, method="decimate", target_faces=max(120, len(faces) // 2))
            parts = T.split(T.bake(vertices, faces, colour, size=256, **look), pieces)
            detail = {"parts": pieces, "faces": int(len(faces))}
        turn = Rotation.random(random_state=int(rng.integers(2 ** 31))).as_matrix()
        factor = {"units": 1.0}.get(kind, float(rng.choice([rng.uniform(0.5, 0.8), rng.uniform(1.25, 2.0)])))
        parts = [Part(p.vertices, p.faces, p.uv, image=p.image, colors=p.colors, roughness=p.roughness, metallic=p.metallic,
                      offset=tuple(a + b for a, b in zip(p.offset, origin))) for p in parts]  # type: ignore[arg-type]
        parts = baked(parts, turn, factor)
        if kind == "split":  # each part its own origin: its centre, stored as the node's offset
            parts = [Part(p.vertices - p.vertices.mean(axis=0), p.faces, p.uv, image=p.image, roughness=p.roughness,
                          metallic=p.metallic, offset=tuple(float(x) for x in p.vertices.mean(axis=0)))  # type: ignore[arg-type]
                     for p in parts]
        detail["rotation_quat"] = [round(float(x), 6) for x in Rotation.from_matrix(turn).as_quat()]
        if kind == "units" and t % 2 == 1:  # centimetres in an OBJ that declares none: read as metres, Y-up
            folder = f"{spec.category}-{spec.variant.lower()}-export-{t + 1}"
            path = root / folder
            path.mkdir(parents=True, exist_ok=True)
            export_obj(parts, path, scale=100.0)
            meta = {"name": f"{spec.variant} {spec.category} (export)", "category": spec.category,
                    "description": spec.description, "source": "another package", "generator": GENERATOR, "seed": seed}
            (path / "metadata.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
            (path / "LICENSE").write_text(LICENSE_TEXT)
            z_up = np.vstack([p.vertices + np.asarray(p.offset) for p in parts]) * 100.0
            read = z_up @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T
            objects.append({"folder": folder, "category": spec.category, "kind": "units", "container": False,
                            "dims_m": [round(float(x), 6) for x in np.ptp(read, axis=0)], "textured": True,
                            "appearance": "image", "n_parts": len(parts), "of": name, "model": f"{folder}/mesh.obj",
                            "source": "folder", "name": meta["name"], "scale": 100.0, "units": "m", "up_axis": "Y",
                            **detail})
            out[kind].append([name, folder, 100.0])
        elif kind == "units":  # millimetres in a GLB (read as metres)
            twin = emit(spec, kind, parts=parts, scale=1000.0, of=name, extra={"scale": 1000.0, **detail})
            out[kind].append([name, twin, 1000.0])
        else:
            twin = emit(spec, kind, parts=parts, of=name, extra={"scale": round(factor, 6), **detail})
            out[kind].append([name, twin, round(factor, 6)])
    return tuple(out.values())


@dataclass
class _Library:
    """The library being written: its folder, seed, the stream of DTC ids and every object planted so far
    (``objects``: ground-truth entries; ``built``: (folder, spec, GLB bytes) of each emitted one)."""

    root: Path
    seed: int
    id_rng: np.random.Generator
    objects: list[dict[str, Any]] = field(default_factory=list)
    built: list[tuple[str, Spec, bytes]] = field(default_factory=list)
    seen: set[str] = field(default_factory=set)

    def folder_name(self, category: str, variant: str) -> str:
        while True:
            name = f"{category.capitalize()}_{dtc_id(self.id_rng)}_{variant}"
            if name not in self.seen:
                self.seen.add(name)
                return name

    def emit(self, spec: Spec, kind: str, *, scale: float = 1.0, parts: list[Part] | None = None,
             of: str | None = None, glb: bytes | None = None, extra: dict[str, Any] | None = None) -> str:
        """One DTC object folder for ``spec`` (as ``kind``: object, container or a trap of ``of``)."""
        parts = parts or spec.parts
        name = self.folder_name(spec.category, spec.variant if kind == "object" or kind == "container" else f"{spec.variant}{kind.title().replace('_', '')}")
        data = glb if glb is not None else export_glb(parts, scale)
        dims = zup_dims(parts, scale)
        meta = {"name": f"{spec.variant} {spec.category}", "category": spec.category, "description": spec.description,
                "object_id": name.split("_")[1], "variant": spec.variant, "generator": GENERATOR, "seed": self.seed}
        write_object(self.root, name, data, meta, preview(parts))
        entry = {"folder": name, "category": spec.category, "kind": kind, "container": spec.container,
                 "dims_m": dims, "textured": True, "model": f"{name}/3d-asset.glb", "source": "dtc",
                 "appearance": "image" if any(p.image is not None for p in parts) else "vertex_color",
                 "n_parts": len(parts), "of": of}
        entry.update(extra or {})
        self.objects.append(entry)
        self.built.append((name, spec, data))
        return name


def _clear(root: Path) -> None:
    """Remove what a previous run wrote under ``root`` (DTC and plain object folders, the ground truth)."""
    if root.exists():
        for child in root.iterdir():  # only what we would write: DTC folders and the ground truth
            if child.is_dir() and (child / "metadata.json").exists() or child.name == "ground_truth.json":  # DTC and plain
                shutil.rmtree(child) if child.is_dir() else child.unlink()
    root.mkdir(parents=True, exist_ok=True)


def _plan(n_objects: int | None) -> tuple[list[tuple[str, Callable[[int, np.random.Generator], Spec], int]], int, int]:
    """The ordinary objects to build (round-robin over categories), the number of containers and of traps
    of each kind."""
    full = sum(n for _, _, n in BUILDERS)
    n_base = full if n_objects is None else max(1, min(int(n_objects), full))
    order: list[tuple[str, Callable[[int, np.random.Generator], Spec], int]] = []
    for k in range(max(n for _, _, n in BUILDERS)):
        order += [(cat, fn, k) for cat, fn, n in BUILDERS if k < n]
    order = order[:n_base]
    n_containers = 6 if n_objects is None else max(1, min(6, n_base // 8))
    n_traps = 2 if n_objects is None or n_base >= 12 else 1
    return order, n_containers, n_traps


def _plant_copies(lib: _Library, bases: list[tuple[str, Spec, bytes]], pick: np.ndarray,
                  n_traps: int) -> dict[str, list[Any]]:
    """Exact copies, recolours, rescales, turned-and-rescaled and re-tessellated copies of ``bases``."""
    exact, recolours, rescales = [], [], []
    for t in range(n_traps):
        name, spec, data = bases[int(pick[t % len(bases)])]
        copy = lib.emit(spec, "copy", glb=data, of=name)
        exact.append([name, copy])
    for t in range(n_traps):
        name, spec, data = bases[int(pick[(n_traps + t) % len(bases)])]
        twin = lib.emit(spec, "recolour", parts=recolour(spec.parts, 0.33 + 0.2 * t), of=name)
        recolours.append([name, twin])
    for t in range(n_traps):
        name, spec, data = bases[int(pick[(2 * n_traps + t) % len(bases)])]
        factor = 1.5 if t % 2 == 0 else 0.6
        twin = lib.emit(spec, "rescale", scale=factor, of=name, extra={"scale": factor})
        rescales.append([name, twin, factor])
    turned, retessellated = [], []
    for t in range(n_traps):  # turned over (another up axis and heading) and rescaled
        name, spec, data = bases[int(pick[(3 * n_traps + t) % len(bases)])]
        angles, factor = [((90.0, 0.0, 37.0), 2.0), ((-60.0, 120.0, 15.0), 0.5)][t % 2]
        twin = lib.emit(spec, "turned", parts=baked(spec.parts, rotation_xyz(angles), factor), of=name,
                        extra={"scale": factor, "rotation_deg": list(angles)})
        turned.append([name, twin, factor])
    for t in range(n_traps):
        name, spec, data = bases[int(pick[(4 * n_traps + t) % len(bases)])]
        twin = lib.emit(spec, "retessellated", parts=subdivide(spec.parts), of=name)
        retessellated.append([name, twin])
    return {"exact_copies": exact, "recolours": recolours, "rescales": rescales, "turned_rescales": turned,
            "retessellated": retessellated}


def _plant_other_source(lib: _Library, bases: list[tuple[str, Spec, bytes]], pick: np.ndarray,
                        n_traps: int) -> list[list[str]]:
    """Another name and source: a plain folder with an OBJ (image-textured objects only: OBJ carries no
    vertex colours everywhere), in centimetres, 1.25x the size, Z-up but read Y-up (undeclared)."""
    other_source = []
    textured_bases = [b for b in (bases[int(i)] for i in pick[5 * n_traps:]) if all(p.image is not None for p in b[1].parts)]
    for t in range(min(n_traps, len(textured_bases))):
        name, spec, data = textured_bases[t]
        folder = f"{spec.category}-{spec.variant.lower()}-scan-{t + 1}"
        path = lib.root / folder
        path.mkdir(parents=True, exist_ok=True)
        export_obj(spec.parts, path, scale=1.25 * 100.0)
        meta = {"name": f"{spec.variant} {spec.category} (scan)", "category": spec.category, "units": "cm",
                "description": spec.description, "source": "another package", "generator": GENERATOR, "seed": lib.seed}
        (path / "metadata.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
        (path / "LICENSE").write_text(LICENSE_TEXT)
        z_up = np.vstack([p.vertices + np.asarray(p.offset) for p in spec.parts]) * 1.25
        read = z_up @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T  # read as Y-up: (x, y, z) -> (x, -z, y)
        lib.objects.append({"folder": folder, "category": spec.category, "kind": "other_source", "container": False,
                            "dims_m": [round(float(x), 6) for x in np.ptp(read, axis=0)], "textured": True,
                            "appearance": "image", "n_parts": len(spec.parts), "of": name, "model": f"{folder}/mesh.obj",
                            "source": "folder", "name": meta["name"], "scale": 1.25, "units": "cm", "up_axis": "Y"})
        other_source.append([name, folder])
    return other_source


def _plant_broken(lib: _Library) -> list[dict[str, str]]:
    """Two broken DTC folders: a truncated GLB and non-mesh bytes named ``3d-asset.glb``."""
    broken = []
    victim = lib.built[0][2]
    for variant, category, payload, reason in (
        ("Truncated", "ball", victim[: len(victim) * 3 // 5], "truncated GLB"),
        ("NotAMesh", "can", b"This is not a mesh, just text saved with a .glb extension.\n" * 4, "not a GLB file"),
    ):
        name = lib.folder_name(category, variant)
        meta = {"name": f"{variant} {category}", "category": category, "description": "a deliberately broken file",
                "object_id": name.split("_")[1], "variant": variant, "generator": GENERATOR, "seed": lib.seed}
        write_object(lib.root, name, payload, meta, preview([Part(np.zeros((1, 3)), np.zeros((0, 3), int), np.zeros((1, 2)), colors=np.full((1, 4), 90, np.uint8))]))
        lib.objects.append({"folder": name, "category": category, "kind": "broken", "container": False, "dims_m": None,
                            "model": f"{name}/3d-asset.glb", "source": "dtc",
                            "textured": False, "appearance": None, "n_parts": 0, "of": None, "expected_error": reason})
        broken.append({"folder": name, "expected_error": reason})
    return broken


def generate_demo_library(root: Path, *, seed: int, n_objects: int | None = None) -> dict[str, Any]:
    """Write the demo library under ``root`` (replacing a previous one) and return the ground truth.

    ``n_objects`` limits the number of ordinary objects (round-robin over categories, so a small
    library still spans many of them); containers and traps scale down with it. Every step draws from
    its own random stream, in a fixed order: the same seed gives the same bytes.
    """
    root = Path(root)
    _clear(root)
    order, n_containers, n_traps = _plan(n_objects)
    lib = _Library(root, seed, np.random.default_rng([seed, 999]))
    for i, (_cat, fn, k) in enumerate(order):
        lib.emit(fn(k, np.random.default_rng([seed, 1, i])), "object")
    for k in range(n_containers):
        lib.emit(CONTAINER_BUILDERS[k % 3](k // 3, np.random.default_rng([seed, 2, k])), "container")

    bases = [(n, s, d) for n, s, d in lib.built if not s.container]
    pick = np.random.default_rng([seed, 3]).permutation(len(bases))
    groups = _plant_copies(lib, bases, pick, n_traps)
    groups["other_source"] = _plant_other_source(lib, bases, pick, n_traps)
    mesh_quality = [lib.emit(build_tote(np.random.default_rng([seed, 4])), "mesh_quality")]
    broken = _plant_broken(lib)
    # copies rebuilt from the surface, as another source publishes a scan (mixcount.demo.traps): planted
    # last and from their own random stream, so every object above keeps its name and bytes; their
    # originals are those of the traps above, so the clean objects stay the same set
    planted = {pair[0] for group in groups.values() for pair in group}
    remeshed, unit_changes, rebaked, split_parts = _republished_traps(
        root, [b for b in bases if b[0] in planted], n_traps, seed, lib.emit, lib.objects)

    objects = lib.objects
    n_broken = len(broken)
    truth = {
        "generator": GENERATOR, "seed": seed, "n_objects": n_objects,
        "objects": objects,
        "containers": [o["folder"] for o in objects if o["container"]],
        **groups, "broken": broken,
        "remeshed": remeshed, "unit_changes": unit_changes, "rebaked": rebaked, "split_parts": split_parts,
        "mesh_quality": mesh_quality,
        "categories": sorted({o["category"] for o in objects if o["kind"] != "broken"}),
        "expected": {"total": len(objects), "active": len(objects) - n_broken, "broken": n_broken,
                     "image_textured": sum(o["appearance"] == "image" for o in objects),
                     "vertex_coloured": sum(o["appearance"] == "vertex_color" for o in objects)},
    }
    (root / "ground_truth.json").write_text(json.dumps(truth, indent=2, sort_keys=True) + "\n")
    return truth
