"""The settings a dataset's scenes were composed with, kept in ``OUT/settings.json`` (no bpy).

A dataset holds one configuration: every scene of ``OUT`` rendered at the same resolution, samples,
passes, scene rules and from the same catalog (object ids name catalog rows: ``exemplars/external/obj_<id>``
is only one object's picture if every scene drew from one catalog). ``compose`` checks the settings of a
run against the file before it writes anything (:func:`check_settings`):

* no file yet: the run's settings become variant 1 (a dataset from before this file: the ``config`` its
  ``dataset.json`` records is taken as variant 1 first, its catalog unknown);
* the same settings as a variant: the run adds scenes to it;
* other settings: :class:`~mixcount.errors.CompositionError` naming every differing key with both values,
  unless the caller allows mixed settings (``compose --mixed-settings``): the run's settings are then
  added as a new variant.

Settings = every key of ``[scene]`` and ``[cycles]``, every ``[compose]`` key but those that only say how
the run goes (:data:`RUN_KEYS`: split, seed, workers, ...; a dataset holds train, val and test scenes
drawn with several seeds), the passes written, and the catalog (:func:`catalog_identity`: its file name
and a hash of its location, no absolute path). Each variant lists the full configuration
hashes its runs had; each scene's ``metadata.json`` records its run's ``config_hash``, and ``merge`` writes
every scene's variant (``settings_id``) and the variants into ``dataset.json``.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Optional

from mixcount.atomic import write_text_atomic
from mixcount.config import Config
from mixcount.errors import CompositionError

SETTINGS_NAME = "settings.json"
SETTINGS_VERSION = 1
DATASET_SECTIONS = ("scene", "cycles", "compose")
# [compose] keys that say how a run goes, not what its scenes are
RUN_KEYS = frozenset({
    "split", "seed", "workers", "render_threads", "recycle_after", "settle_ahead", "ray_cpus_per_worker",
    "scene_timeout_s", "max_attempts_factor", "preview_scenes", "mesh_cache", "merge",
    "device", "ray_gpus_per_worker",  # where Cycles renders (each scene records it: metadata.json render_device)
    "min_object_px",  # the floor a run's pixels per counted object are said against, not what a scene is
})
CATALOG_KEY = "catalog"


def _flatten(data: Any, prefix: str, out: dict[str, Any]) -> None:
    if isinstance(data, dict):
        for key in sorted(data):
            _flatten(data[key], f"{prefix}.{key}" if prefix else str(key), out)
    else:
        out[prefix] = data


def settings_of_config(config: dict[str, Any]) -> dict[str, Any]:
    """The dataset-defining keys of a configuration (as ``Config.to_dict`` gives it), flat and dotted."""
    flat: dict[str, Any] = {}
    for section in DATASET_SECTIONS:
        _flatten(config.get(section, {}), section, flat)
    return {k: v for k, v in flat.items() if not (k.startswith("compose.") and k[len("compose."):] in RUN_KEYS)}


def catalog_identity(url: str) -> str:
    """A catalog as the dataset records it: the database file's name and a hash of its full location
    (``a.db#3f2a9c01d4e7``), so no dataset file holds an absolute path of the machine that composed it."""
    from sqlalchemy.engine import make_url

    parsed = make_url(url)
    name = Path(parsed.database).name if parsed.database else parsed.get_backend_name()
    where = parsed.render_as_string(hide_password=True)
    if parsed.get_backend_name() == "sqlite" and parsed.database and parsed.database != ":memory:":
        where = str(Path(parsed.database).resolve())
    return f"{name}#{hashlib.sha256(where.encode()).hexdigest()[:12]}"


def dataset_settings(config: Config, *, passes: Optional[list[str]] = None, catalog: Optional[str] = None
                     ) -> dict[str, Any]:
    """The settings of one compose run: :func:`settings_of_config`, the passes actually written (``passes``
    given by the caller wins over ``compose.passes``) and the catalog (None: not known to the caller)."""
    settings = settings_of_config(config.to_dict())
    if passes is not None:
        settings["compose.passes"] = list(passes)
    if catalog is not None:
        settings[CATALOG_KEY] = catalog_identity(catalog)
    return dict(json.loads(json.dumps(settings)))  # tuples -> lists: equal to what the file holds


def read_settings(out_dir: Path) -> dict[str, Any]:
    """``OUT/settings.json`` (``{"version", "variants": [...]}``); a dataset without one gets the variant its
    ``dataset.json`` config implies, or none. A damaged file is a CompositionError (never overwritten)."""
    path = Path(out_dir) / SETTINGS_NAME
    try:
        data = json.loads(path.read_text())
        if not isinstance(data.get("variants"), list):
            raise ValueError("no variants list")
        return dict(data)
    except FileNotFoundError:
        pass
    except (OSError, ValueError, AttributeError) as exc:
        raise CompositionError(f"{path} cannot be read ({exc}): restore it, or compose into a new --out") from None
    variants: list[dict[str, Any]] = []
    try:
        old = json.loads((Path(out_dir) / "dataset.json").read_text())
        if isinstance(old.get("config"), dict) and old["config"]:
            variants.append({"id": 1, "settings": settings_of_config(old["config"]),
                             "config_hashes": [old["config_hash"]] if old.get("config_hash") else []})
    except (OSError, ValueError, AttributeError):
        pass
    return {"version": SETTINGS_VERSION, "variants": variants}


def differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``key old -> new`` for every key whose value differs (a key only one side has included); the
    catalog is compared only when both sides know it."""
    keys = sorted(set(old) | set(new))
    out = []
    for key in keys:
        if key == CATALOG_KEY and (key not in old or key not in new):
            continue
        if old.get(key, "(unset)") != new.get(key, "(unset)"):
            out.append(f"{key} {json.dumps(old.get(key, '(unset)'))} there, {json.dumps(new.get(key, '(unset)'))} now")
    return out


def check_settings(out_dir: Path, settings: dict[str, Any], config_hash: str, *, allow_mixed: bool) -> int:
    """Check a run's ``settings`` against ``OUT``'s and record them (see the module docstring); returns
    the run's variant id. Raises CompositionError, writing nothing, when they differ and mixing is not
    allowed."""
    out_dir = Path(out_dir)
    data = read_settings(out_dir)
    variants: list[dict[str, Any]] = data["variants"]
    match = next((v for v in variants if not differences(v.get("settings", {}), settings)), None)
    if match is None and variants and not allow_mixed:
        last = variants[-1]
        diff = differences(last.get("settings", {}), settings)
        raise CompositionError(
            f"{out_dir} holds scenes composed with other settings ({'; '.join(diff)}). A dataset holds one "
            "configuration: compose into a new --out, or pass --mixed-settings to add these scenes with their "
            f"own settings (recorded in {SETTINGS_NAME}; dataset.json then says which scenes hold which); "
            "nothing was written")
    if match is None:
        match = {"id": max((int(v.get("id", 0)) for v in variants), default=0) + 1, "settings": settings,
                 "config_hashes": []}
        variants.append(match)
    elif CATALOG_KEY in settings and CATALOG_KEY not in match.get("settings", {}):
        match["settings"] = {**match.get("settings", {}), CATALOG_KEY: settings[CATALOG_KEY]}
    if config_hash not in match["config_hashes"]:
        match["config_hashes"].append(config_hash)
    data["version"] = SETTINGS_VERSION
    out_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_dir / SETTINGS_NAME, json.dumps(data, indent=1, sort_keys=True))
    return int(match["id"])


def variant_of_hash(out_dir: Path) -> dict[str, int]:
    """Config hash -> variant id, from ``OUT/settings.json`` (empty without one)."""
    try:
        data = json.loads((Path(out_dir) / SETTINGS_NAME).read_text())
        return {str(h): int(v["id"]) for v in data.get("variants", []) for h in v.get("config_hashes", [])}
    except (OSError, ValueError, AttributeError, KeyError, TypeError):
        return {}


def variants_summary(out_dir: Path) -> list[dict[str, Any]]:
    """The variants of ``OUT/settings.json`` for dataset.json: id, settings, config hashes."""
    try:
        data = json.loads((Path(out_dir) / SETTINGS_NAME).read_text())
        return [dict(v) for v in data.get("variants", []) if isinstance(v, dict)]
    except (OSError, ValueError, AttributeError):
        return []
