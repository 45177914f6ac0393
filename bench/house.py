"""The house's figures (issue 58), printed as one JSON line: how far compose settings travel, private names
imported across modules, import circles, the longest files and functions, docs/performance.md's length and
the repeated blocks the ``duplicates`` tool finds.

Why a bench and not a test: these are figures to compare before and after a change; the rules they stand
for (no private import across modules, no circle, no file over 520 lines without a reason) are asserted
in ``tests/test_code_shape.py``.

The config path is measured, not read: compose runs one scene of the given catalog under ``sys.settrace``
in this process, and every mixcount function entered while one of its locals *is* the run's ``Config``
(or one of its sections), or holds it one attribute down (``self`` of a ``ComposeJob`` or of the run's
loop state: the config travels inside it), is a place visited. Not places: a comprehension's own frame
(``<genexpr>``, ``<listcomp>``: part of its function) and the config's own methods in the modules that
type it (:data:`HOME`: ``to_dict``, ``hash``, a property: the config answering about itself went nowhere).
A climb is a step from a module in a lower room back up to one in a higher room (rooms as
tests/test_code_shape.py orders them): the configuration picked up again higher up after a lower room had
it. A handoff is one (caller module -> callee module) pair across which the config was passed, the caller
being the nearest enclosing frame that holds it too; ``handoff_pairs`` lists them.

    python bench/house.py --smoke               # static figures only (what tests/test_benches.py runs)
    python bench/house.py                       # and the duplicates tool's count
    python bench/house.py --db catalog/catalog.db --config-path   # and the config path (composes 1 scene)
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "mixcount"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from import_graph import import_circles, import_graph, package_modules  # noqa: E402  (tests/import_graph.py)
from test_code_shape import private_imports  # noqa: E402  (the rule the test asserts, every import form)

FILE_LIMIT = 520
HOME = ("mixcount.config", "mixcount.scene_config")  # where the config is typed: its own methods are not places


def long_files(limit: int = FILE_LIMIT) -> dict[str, int]:
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in PACKAGE.rglob("*.py")}
    return dict(sorted(((k, v) for k, v in sizes.items() if v > limit), key=lambda kv: -kv[1]))


def duplicate_pairs() -> Any:
    if shutil.which("duplicates") is None:
        return None
    text = subprocess.run(["duplicates", "--most", "200", "--seconds", "120"], cwd=ROOT, capture_output=True,
                          text=True).stdout
    first = text.splitlines()[0] if text else ""
    rows = [ln for ln in text.splitlines() if ln.startswith("D")]
    return {"summary": first, "not_boilerplate": sum("boilerplate" not in r and "migrations/" not in r for r in rows)}


def config_path(db: str) -> dict[str, Any]:
    """Compose one scene of ``db``'s train split under a tracer; the mixcount places that hold the config."""
    from test_code_shape import LEVEL, _room  # the rooms, lowest first

    def room_level(module: str) -> int:
        return LEVEL[_room(module)]

    from mixcount import api

    visits: list[tuple[str, str]] = []
    watched: list[int] = []
    handoffs: set[str] = set()  # "caller module -> callee module": the config handed across a module line

    def tracer(frame: Any, event: str, arg: Any) -> Any:
        if event != "call":
            return None
        mod = frame.f_globals.get("__name__", "")
        if not mod.startswith("mixcount") or not watched:
            return None
        if frame.f_code.co_name.startswith("<"):  # a comprehension's frame is part of its function, not a place
            return None
        if mod in HOME:  # the config answering about itself (to_dict, hash, a property): it went nowhere
            return None
        if holds_config(frame):
            place = (mod, frame.f_code.co_name)
            if not visits or visits[-1] != place:
                visits.append(place)
            caller = frame.f_back
            while caller is not None and not (caller.f_globals.get("__name__", "").startswith("mixcount")
                                              and caller.f_globals["__name__"] not in HOME
                                              and not caller.f_code.co_name.startswith("<") and holds_config(caller)):
                caller = caller.f_back
            if caller is not None and caller.f_globals["__name__"] != mod:
                handoffs.add(f"{caller.f_globals['__name__']} -> {mod}")
        return None

    def holds_config(frame: Any) -> bool:
        return any(id(v) in watched or any(id(a) in watched for a in getattr(v, "__dict__", {}).values())
                   for v in frame.f_locals.values())

    import mixcount.config as config_module

    real_load = config_module.load_config

    def load_and_watch(*a: Any, **k: Any) -> Any:
        cfg = real_load(*a, **k)
        watched.extend(id(getattr(cfg, f)) for f in vars(cfg) if not f.startswith("_"))
        watched.append(id(cfg))
        return cfg

    config_module.load_config = load_and_watch
    with tempfile.TemporaryDirectory() as tmp:
        sys.settrace(tracer)
        try:
            api.compose(api.open_catalog(db), Path(tmp) / "out", n=1, split="train", config=["quick"], resolution=64,
                        samples=2)
        finally:
            sys.settrace(None)
            config_module.load_config = real_load
    mods_seen = []
    for mod, _ in visits:
        if not mods_seen or mods_seen[-1] != mod:
            mods_seen.append(mod)
    climbs = sum(1 for a, b in zip(mods_seen, mods_seen[1:]) if room_level(b) > room_level(a))
    return {"places": len(set(visits)), "modules": len({m for m, _ in visits}), "steps": len(mods_seen),
            "climbs": climbs, "handoffs": len(handoffs), "handoff_pairs": sorted(handoffs),
            "path": [f"{m}:{f}" for m, f in visits]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--db", help="a catalog with captioned, split objects (for --config-path)")
    ap.add_argument("--config-path", action="store_true", help="trace compose's config (composes 1 scene)")
    ap.add_argument("--no-duplicates", action="store_true", help="skip the duplicates tool")
    ap.add_argument("--smoke", action="store_true", help="the static figures only (no duplicates tool, no compose)")
    args = ap.parse_args()
    if args.smoke:
        args.no_duplicates, args.config_path = True, False
    mods = package_modules(PACKAGE)
    graph = import_graph(mods)
    perf = ROOT / "docs" / "performance.md"
    figures: dict[str, Any] = {
        "private_imports": private_imports(),
        "import_circles": import_circles(graph),
        "files_over_520": long_files(),
        "longest_files": dict(sorted(((str(mods[m][0].relative_to(ROOT)), len(mods[m][0].read_text().splitlines()))
                                      for m in mods), key=lambda kv: -kv[1])[:5]),
        "performance_md_lines": len(perf.read_text().splitlines()) if perf.exists() else None,
    }
    figures["private_import_count"] = len(figures["private_imports"])
    if not args.no_duplicates:
        figures["duplicates"] = duplicate_pairs()
    if args.config_path:
        if not args.db:
            ap.error("--config-path needs --db")
        figures["config_path"] = config_path(args.db)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
