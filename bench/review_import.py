"""`catalog review import` at scale: decisions files of 2,000, 8,000 and 200,000 entries.

Usage: .venv/bin/python bench/review_import.py [--sizes 2000 8000 200000] [--pairs 0] [--smoke]

For each size: a fresh catalog (migrated SQLite) with one object per entry, inserted in bulk, and a
``mixcount-review-v1`` file as the review page writes it (pretty-printed; accept and reject alternating,
every tenth entry also a container setting; ``--pairs`` adds that many pair decisions). Timed: the
first import (check, record, apply) and the same file again (everything already recorded). The catalog
is checked afterwards (the statuses the file asks for). Prints human lines to stderr and one JSON line
to stdout: {"sizes": [{"n", "pairs", "import_s", "again_s", "per_entry_ms", "recorded", "status_changes"}]}
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from datetime import datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from sqlalchemy import func, insert, select  # noqa: E402

from mixcount.catalog.db import open_catalog  # noqa: E402
from mixcount.catalog.models import CatalogObject  # noqa: E402
from mixcount.curation.review.import_decisions import import_decisions  # noqa: E402


def build(folder: Path, n: int, n_pairs: int) -> tuple[object, Path]:
    catalog = open_catalog(f"sqlite:///{folder / 'catalog.db'}", data_dir=str(folder / "data"))
    rows = [{"id": i, "source": "folder", "source_id": f"/lib/obj_{i:06d}.glb", "name": f"obj_{i:06d}",
             "category": "mug", "model_path": f"/lib/obj_{i:06d}.glb", "status": "active"} for i in range(1, n + 1)]
    with catalog.session() as session:
        for k in range(0, n, 20000):
            session.execute(insert(CatalogObject), rows[k:k + 20000])
        session.commit()
    start = datetime(2026, 11, 23, 13, 0, 0)
    decisions = []
    for i in range(1, n + 1):
        entry = {"id": i, "name": f"obj_{i:06d}", "decision": "reject" if i % 2 else "accept",
                 "note": "", "decided_at": (start + timedelta(milliseconds=i)).isoformat(timespec="milliseconds") + "Z"}
        if i % 10 == 0:
            entry["container"] = True
        decisions.append(entry)
    pairs = [{"a": i, "b": i + 1, "a_name": f"obj_{i:06d}", "b_name": f"obj_{i + 1:06d}", "decision": "variants",
              "note": "", "decided_at": (start + timedelta(seconds=1, milliseconds=i)).isoformat(timespec="milliseconds") + "Z"}
             for i in range(1, min(n_pairs, n - 1) + 1)]
    doc = {"format": "mixcount-review-v1", "catalog": catalog.url, "reviewer": "bench",  # type: ignore[attr-defined]
           "exported_at": "2026-11-23T14:00:00.000Z", "decisions": decisions, "pairs": pairs}
    path = folder / "decisions.json"
    path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return catalog, path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[2000, 8000, 200000])
    ap.add_argument("--pairs", type=int, default=0)
    ap.add_argument("--smoke", action="store_true", help="one small size (CI)")
    args = ap.parse_args()
    sizes = [300] if args.smoke else args.sizes
    out = []
    for n in sizes:
        with tempfile.TemporaryDirectory() as tmp:
            catalog, path = build(Path(tmp), n, args.pairs)
            t0 = time.perf_counter()
            summary = import_decisions(catalog, path)  # type: ignore[arg-type]
            t1 = time.perf_counter()
            again = import_decisions(catalog, path)  # type: ignore[arg-type]
            t2 = time.perf_counter()
            with catalog.session() as session:  # type: ignore[attr-defined]
                excluded = session.scalar(select(func.count()).where(CatalogObject.status == "excluded"))
                containers = session.scalar(select(func.count()).where(CatalogObject.container.is_(True)))
            catalog.close()  # type: ignore[attr-defined]
            assert excluded == (n + 1) // 2 and containers == n // 10, (excluded, containers)
            assert again.recorded == 0 and not again.status_changes
            row = {"n": n, "pairs": args.pairs, "file_mb": round(path.stat().st_size / 1e6, 1),
                   "import_s": round(t1 - t0, 2), "again_s": round(t2 - t1, 2),
                   "per_entry_ms": round((t1 - t0) / n * 1000, 4), "recorded": summary.recorded,
                   "status_changes": len(summary.status_changes)}
            print(f"{n} entries ({row['file_mb']} MB): import {row['import_s']} s "
                  f"({row['per_entry_ms']} ms/entry), again {row['again_s']} s; {summary.recorded} recorded, "
                  f"{len(summary.status_changes)} status changes", file=sys.stderr)
            out.append(row)
    print(json.dumps({"sizes": out}))


if __name__ == "__main__":
    main()
