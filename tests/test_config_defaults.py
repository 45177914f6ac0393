"""``configs/default.toml`` is the only place a default lives.

(a) Every TOML section loads into a frozen dataclass whose fields are exactly the section's keys and carry
no default value. (b) No code under mixcount/ or bench/ re-defaults a config key: no ``x.get("<key>", d)``,
no ``getattr(o, "<key>", d)``, no literal default for a parameter named after a config key, and no
class-level field named after a config key with a literal default (``passes: tuple = (...)`` in a
dataclass, ``field(default=...)``): a request or task dataclass carries what the configuration says.
"""

from __future__ import annotations

import ast
import dataclasses
import tomllib
from pathlib import Path

import pytest

from mixcount.config import DEFAULT_CONFIG, Config, load_config

PROJECT_ROOT = Path(__file__).resolve().parent.parent

TOML = tomllib.loads(DEFAULT_CONFIG.read_text())
SCANNED = [p for d in ("mixcount", "bench") for p in sorted((PROJECT_ROOT / d).rglob("*.py"))]


def _key_names() -> dict[str, str]:
    """Config key -> the ``section.key`` names it stands for. A key with a group prefix (``settle_``,
    ``physics_``) also counts without it, as a worker request spells it (``penetration_fraction``)."""
    names: dict[str, list[str]] = {}
    for section, keys in TOML.items():
        for key in keys:
            names.setdefault(key, []).append(f"{section}.{key}")
            head, _, rest = key.partition("_")
            if head in ("settle", "physics") and rest:
                names.setdefault(rest, []).append(f"{section}.{key}")
    return {k: " / ".join(v) for k, v in names.items()}


KEYS = _key_names()

# Parameters that share a config key's name but mean something else (checked by hand; keep it short).
NOT_CONFIG_PARAMS = {
    ("mixcount/captions/colours.py", "samples"),  # surface points sampled for colour clustering
    ("mixcount/captions/colours.py", "seed"),  # seed of that point sampling
    ("mixcount/dataset/scene_writer.py", "margin"),  # exemplar crop margin, not the canonical render's
    ("mixcount/demo/library.py", "scale"),  # glTF node scale of a generated model
    ("mixcount/demo/writers.py", "scale"),  # ... the same, where the GLB is written
    ("mixcount/demo/demo_pools.py", "seed"),  # fixture pool for tests and benchmarks: a fixed generator seed
    ("mixcount/demo/demo_pools.py", "split"),  # ... and the split label it gives every object
    ("mixcount/evaluate/metrics.py", "split"),  # which ground-truth COCO file to score against
    ("mixcount/demo/demo_pools.py", "min_faces"),  # faces of a heavy benchmark model, not the degenerate threshold
    ("bench/pools.py", "min_faces"),  # ... the same
}
# Class-level fields that share a config key's name but mean something else (checked by hand).
NOT_CONFIG_FIELDS = {
    ("mixcount/captions/stub.py", "provider"),  # the stub captioner's own name in caption records ("offline")
    ("mixcount/captions/stub.py", "model"),  # ... and its model name ("stub")
    ("mixcount/dataset/merge.py", "categories"),  # a merged split's COCO categories, not container categories
}
# ``.get(key, default)`` on data that is not configuration but shares a key's name (checked by hand).
NOT_CONFIG_GETS = {
    ("mixcount/catalog/layouts/gso.py", "categories"),  # the ``categories`` field of a GSO metadata.pbtxt
    ("mixcount/scene/spec.py", "collision_proxies"),  # a stage written before proxies existed: none
    ("mixcount/scene/spec.py", "rest_speed"),  # ... and before early stopping: all frames
    ("mixcount/scene/spec.py", "floor_collider_depth"),  # ... and before the deep floor collider: the floor
    ("mixcount/scene/spec.py", "denoise_prefilter"),  # ... and before the prefilter was a setting: Blender's
}


def test_every_section_is_a_frozen_dataclass_of_exactly_the_toml_keys():
    cfg = load_config()
    section_fields = {f.name for f in dataclasses.fields(Config) if f.name not in ("sources", "data")}
    assert section_fields == set(TOML), "Config must have one attribute per TOML section"
    for section, keys in TOML.items():
        obj = getattr(cfg, section)
        assert dataclasses.is_dataclass(obj), section
        assert type(obj).__dataclass_params__.frozen, f"[{section}] dataclass must be frozen"
        fields = dataclasses.fields(obj)
        assert {f.name for f in fields} == set(keys), f"[{section}] fields differ from default.toml"
        defaulted = [f.name for f in fields
                     if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING]
        assert not defaulted, f"[{section}] fields carry code defaults: {defaulted}"
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, fields[0].name, None)


def test_values_are_the_toml_values():
    cfg = load_config()
    for section, keys in TOML.items():
        for key, value in keys.items():
            got = getattr(getattr(cfg, section), key)
            assert (list(got) if isinstance(got, tuple) else got) == value, f"{section}.{key}"


def _literal(node: ast.AST | None) -> bool:
    if node is None:
        return False
    if isinstance(node, ast.Constant):
        return node.value is not None
    if isinstance(node, (ast.Tuple, ast.List)):
        return all(_literal(e) for e in node.elts)
    if isinstance(node, ast.UnaryOp):
        return _literal(node.operand)
    return False


def _field_default(node: ast.AST | None) -> bool:
    """``field(default=<literal>)`` or ``field(default_factory=...)`` (any factory: it makes a value)."""
    return (isinstance(node, ast.Call) and isinstance(node.func, (ast.Name, ast.Attribute))
            and (node.func.id if isinstance(node.func, ast.Name) else node.func.attr) == "field"
            and any((kw.arg == "default" and _literal(kw.value)) or kw.arg == "default_factory"
                    for kw in node.keywords))


def code_defaults(path: Path, rel: str | None = None) -> list[str]:
    """Every place in ``path`` that supplies its own value for a config key."""
    rel = rel or path.relative_to(PROJECT_ROOT).as_posix()
    tree = ast.parse(path.read_text(), filename=rel)
    found: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            key = node.args[0].value
            has_default = len(node.args) >= 2 or any(kw.arg == "default" for kw in node.keywords)
            if isinstance(node.func, ast.Attribute) and node.func.attr in ("get", "setdefault") and has_default \
                    and key in KEYS and (rel, key) not in NOT_CONFIG_GETS:
                found.append(f"{rel}:{node.lineno} .{node.func.attr}({key!r}, ...) re-defaults {KEYS[key]}")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr" \
                and len(node.args) == 3 and isinstance(node.args[1], ast.Constant) and node.args[1].value in KEYS \
                and _literal(node.args[2]):
            found.append(f"{rel}:{node.lineno} getattr(..., {node.args[1].value!r}, default)")
        if isinstance(node, ast.ClassDef):
            for stmt in node.body:
                target = stmt.target if isinstance(stmt, ast.AnnAssign) else (
                    stmt.targets[0] if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 else None)
                if not isinstance(target, ast.Name) or target.id not in KEYS or (rel, target.id) in NOT_CONFIG_FIELDS:
                    continue
                if _literal(stmt.value) or _field_default(stmt.value):
                    found.append(f"{rel}:{stmt.lineno} class {node.name}: field {target.id} = "
                                 f"{ast.unparse(stmt.value)} re-defaults {KEYS[target.id]}")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            a = node.args
            positional = a.posonlyargs + a.args
            pairs = list(zip(positional[len(positional) - len(a.defaults):], a.defaults))
            pairs += [(arg, d) for arg, d in zip(a.kwonlyargs, a.kw_defaults)]
            for arg, default in pairs:
                if arg.arg in KEYS and _literal(default) and (rel, arg.arg) not in NOT_CONFIG_PARAMS:
                    name = getattr(node, "name", "<lambda>")
                    found.append(f"{rel}:{node.lineno} {name}({arg.arg}={ast.unparse(default)}) "
                                 f"re-defaults {KEYS[arg.arg]}")
    return found


def test_no_code_defaults_for_config_keys():
    found = [hit for path in SCANNED for hit in code_defaults(path)]
    assert not found, "config values defaulted in code (default.toml is the only place):\n" + "\n".join(found)


def test_scan_catches_known_offender_shapes(tmp_path: Path):
    """The scanner itself: each shape of re-default it must catch, in a throwaway module."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "def a(comp):\n    return comp.get('scene_timeout_s', 900.0)\n"
        "def b(job):\n    return job.get('world_strength', 1.0)\n"
        "def c(settle):\n    return settle.get('penetration_fraction', 0.15)\n"
        "def d(cfg, o):\n    return getattr(cfg, 'samples', 32), getattr(o, 'split', None)\n"
        "def e(scene, *, sun_strength=2.0):\n    return sun_strength\n"
        "def f(meta):\n    return meta.get('visibility_unrelated', 1), meta.get('samples')\n"
        "@dataclass(frozen=True)\nclass Task:\n    spec: object\n    passes: tuple = ('instance', 'depth')\n"
        "    mesh_cache: str = field(default='zstd')\n    seed: int = field(default_factory=int)\n"
        "    captions: dict = field(default_factory=dict)\n    depth_format: str\n"
    )
    hits = code_defaults(probe, "mixcount/probe.py")
    assert len(hits) == 8, hits
    assert any("class Task: field passes = ('instance', 'depth') re-defaults compose.passes" in h for h in hits)
    assert any("field mesh_cache" in h for h in hits) and any("field seed" in h for h in hits)
    assert any("compose.scene_timeout_s" in h for h in hits)
    assert any("scene.settle_penetration_fraction" in h for h in hits)
    assert any("canonical_render.sun_strength" in h for h in hits)
