"""Count targets: what scenes asked for a number of *visible* objects keep (issue 37's figures).

    .venv/bin/python bench/counts.py --work W --counts uniform:1-200 --scenes 60 --pool heavy --paper
    .venv/bin/python bench/counts.py --work W --counts uniform:1-200,imbalance:2-4 --scenes 20 --pool heavy
    .venv/bin/python bench/counts.py --work W --counts uniform:1000-1000 --scenes 1 --resolution 1024 --pool heavy

Scenes are sampled with the default config and ``scene.count_target`` = ``--counts`` from the chosen pool
(bench/pools.py: ``heavy`` = the capture-like >= 200k-face demo copy, ``light`` = the demo library) and run
end to end by the worker, as compose does: a seed whose scene cannot be brought to its target (or comes out
empty / rejected) is regenerated from the next seed, until ``--scenes`` scenes are kept. ``--paper`` then
runs the paper's rule (spawned n ~ UniformInt[30, 200]) on the same seeds for the time ratio.

stdout: one JSON line per run: the figures of :func:`mixcount.evaluate.count_stats.summarise_counts` (exact
and within-tolerance shares, KS distance against the target distribution, per-bin counts, per-class offsets
and imbalance, the scenes regenerated with why), seconds per kept scene (the regenerated seeds' time
included), physics and RGB seconds, and the worker's peak resident memory. stderr: one line per scene.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
sys.path.append(str(ROOT))


def _worker_peak_mb(worker: Any) -> Optional[float]:
    """The bpy worker's peak resident memory (VmHWM of its process), MB; None when not readable."""
    pid = getattr(getattr(worker, "proc", None), "pid", None) or getattr(worker, "pid", None)
    if pid is None:
        return None
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        return None
    return None


def _worker_cpu_s(worker: Any) -> Optional[float]:
    """The bpy worker's user + system CPU seconds so far (/proc/PID/stat); None when not readable. Per scene
    deltas of it weigh the work free of the other load on a shared machine."""
    import os

    pid = getattr(getattr(worker, "proc", None), "pid", None) or getattr(worker, "pid", None)
    if pid is None:
        return None
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def scene_look(scene_dir: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """How a finished scene looks in cam_0 (issue 48): the share of the image its counted objects cover
    (instance.png pixels of kept counted ids), the median visible pixels of a counted object, the counted
    objects' union box (of their pixels) over the image, and the counted pixels' mean luminance in rgb.png
    (Rec. 709 weights of the 8-bit sRGB values, 0-1)."""
    import numpy as np
    from PIL import Image

    counted = [o for o in meta["objects"] if o.get("role") == "counted" and o.get("status") == "kept"]
    ids = np.array(Image.open(scene_dir / "instance.png"))
    mask = np.isin(ids, np.array([o["instance_id"] for o in counted], dtype=ids.dtype))
    px = [float(o.get("visible_px") or 0) for o in counted]
    out: dict[str, Any] = {"image_share": round(float(mask.mean()), 4),
                           "visible_px_median": float(np.median(px)) if px else None}
    if mask.any():
        ys, xs = np.nonzero(mask)
        out["union_box"] = round(float((ys.max() - ys.min() + 1) * (xs.max() - xs.min() + 1)) / mask.size, 4)
        rgb = np.asarray(Image.open(scene_dir / "rgb.png").convert("RGB"), dtype=np.float64) / 255.0
        out["luminance"] = round(float((rgb[mask] @ np.array([0.2126, 0.7152, 0.0722])).mean()), 4)
    if meta["spec"].get("container") is not None:
        out["container"] = True
    out.update(reframed(meta, counted))
    return out


def reframed(meta: dict[str, Any], counted: list[dict[str, Any]]) -> dict[str, Any]:
    """What framing cam_0 on the final pile (the kept counted objects, after any take-out and top-up) would
    change against the camera written (framed on the first settle's pile): the distance ratio and the
    look-at's shift over the distance (:func:`mixcount.scene.framing.frame_camera`, the same rule)."""
    import numpy as np

    from mixcount.scene.framing import frame_camera
    from mixcount.scene.spec import CameraSpec

    written = meta["cameras"][0].get("framing") or {}
    if "distance" not in written or not counted:
        return {}
    cam = CameraSpec.from_dict(meta["spec"]["cameras"][0])
    centres = np.array([np.asarray(o["matrix_world"])[:3, 3] for o in counted])
    sizes = np.array([float(o["size_m"]) for o in counted])
    cont = meta["spec"].get("container")
    diag = float(np.linalg.norm(cont["extent_m"])) if cont else None
    margin = float((meta["spec"].get("placement") or {}).get("frame_margin", 0.0))
    again = frame_camera(cam, centres, sizes, diag, margin=margin)
    d0 = float(written["distance"])
    shift = np.linalg.norm(np.asarray(again.camera.look_at) - np.asarray(written["camera"]["look_at"]))
    return {"reframe_distance_ratio": round(float(again.camera.distance) / d0, 4),
            "reframe_shift": round(float(shift) / d0, 4)}


def write_coco(scene_dirs: list[Path], path: Path) -> int:
    """The scenes' own coco.json files merged into one COCO instances file (image ids renumbered, the
    annotations' ``is_distractor``, ``area`` and ``bbox`` kept, masks left out): the paper run's histogram,
    and its per-category counts by object size, for ``--counts histogram:PATH``."""
    images, annotations, categories = [], [], {}
    for n, d in enumerate(sorted(scene_dirs), 1):
        doc = json.loads((d / "coco.json").read_text())
        first = min(img["id"] for img in doc["images"])
        for img in doc["images"]:
            if img["id"] == first:  # cam_0
                images.append({**img, "id": n})
        for a in doc["annotations"]:
            if a["image_id"] == first:
                kept = {k: a[k] for k in ("area", "bbox") if k in a}
                annotations.append({"id": len(annotations) + 1, "image_id": n, "category_id": a["category_id"],
                                    "is_distractor": bool(a.get("is_distractor", False)), **kept})
        categories.update({c["id"]: {"id": c["id"], "name": c.get("name")} for c in doc["categories"]})
    path.write_text(json.dumps({"images": images, "annotations": annotations, "categories": list(categories.values())}))
    return len(images)


class Run:
    """One count target's scenes on its own worker, one kept scene per :meth:`step` (regenerated seeds
    included), so two runs can alternate and share the machine's load evenly."""

    def __init__(self, counts: str, args: Any, work: Path, worker: Any, pool: list[Any], label: str) -> None:
        from mixcount.config import load_config
        from mixcount.counts.targets import parse_count_target

        self.counts, self.args, self.work, self.worker, self.pool, self.label = counts, args, work, worker, pool, label
        self.cfg = load_config([], [f"compose.resolution={args.resolution}", f"compose.samples={args.samples}",
                                    f"scene.count_target={counts}", *args.set])
        self.dist = parse_count_target(counts)
        self.rows: list[dict[str, Any]] = []
        self.rejected: list[dict[str, Any]] = []
        self.failed: list[dict[str, Any]] = []
        self.seconds = self.physics = self.rgb = 0.0
        self.seed = args.seed
        self.oracle_lines: list[dict[str, Any]] = []
        self.looks: list[dict[str, Any]] = []

    @property
    def done(self) -> bool:
        scenes = self.args.paper_scenes if self.dist.is_paper and self.args.paper_scenes else self.args.scenes
        return len(self.rows) >= scenes or self.seed >= self.args.seed + scenes * 3 + 4

    def step(self) -> None:
        """Seeds from the next one until a scene is kept (or the seed budget is spent)."""
        kept = len(self.rows)
        while len(self.rows) == kept and not self.done:
            self._one(self.seed)
            self.seed += 1

    def _one(self, seed: int) -> None:
        from pools import run_fresh_scene, warm_mesh_cache, with_proxies

        from mixcount.evaluate.count_stats import rejected_record, scene_record
        from mixcount.scene.sampler import sample_scene
        from mixcount.usd.stage import convert_scene_assets

        args, cfg = self.args, self.cfg
        spec = with_proxies(sample_scene(seed, "train", cfg, self.pool), self.work / "proxies",
                            cfg.ingest.proxy_max_vertices)
        converted = convert_scene_assets(spec, self.work / "assets")
        warm_mesh_cache(self.worker, converted, cfg.compose.mesh_cache)
        t_scene = time.perf_counter()
        cpu0 = _worker_cpu_s(self.worker)
        out = self.work / f"out_{self.label}" / f"seed_{seed}"
        outcome, meta, stages = run_fresh_scene(self.worker, spec, out, self.work / "assets", timeout_s=args.timeout,
                                                threads=args.threads, mesh_cache=cfg.compose.mesh_cache,
                                                oracle=args.oracle)
        dt = time.perf_counter() - t_scene
        cpu1 = _worker_cpu_s(self.worker)
        self.seconds += dt
        line: dict[str, Any] = {"bench": "counts.scene", "run": self.label, "seed": seed, "seconds": round(dt, 2),
                                "spawned": spec.n_counted, "status": outcome.status}
        if cpu0 is not None and cpu1 is not None:
            line["worker_cpu_s"] = round(cpu1 - cpu0, 2)
        if meta is not None:
            rec = scene_record(meta) if not self.dist.is_paper else {"kept": meta["n_counted"]}
            self.rows.append(rec or {})
            self.physics += stages.get("physics", 0.0)
            self.rgb += stages.get("rgb", 0.0)
            line.update({"target": (rec or {}).get("target"), "kept": (rec or {}).get("kept", meta["n_counted"]),
                         "physics_s": stages.get("physics"), "rgb_s": stages.get("rgb"),
                         "path": str(outcome.path), **scene_look(Path(outcome.path), meta)})
            self.looks.append(line)
            if args.oracle:
                kept_objs = [o for o in meta["objects"] if o.get("status") == "kept"]
                ious = [o["oracle_iou"] for o in kept_objs if o.get("oracle_iou") is not None]
                v_t = meta["visibility_threshold"]
                line.update({"oracle_objects": len(ious), "oracle_iou_min": round(min(ious), 4) if ious else None,
                             "oracle_iou_mean": round(sum(ious) / len(ious), 4) if ious else None,
                             # the keep rule (> 1 - v_t visible) read from the one-render-per-object masks
                             "oracle_below_rule": sum(1 for o in kept_objs
                                                      if (o.get("oracle_visibility") or 0.0) <= 1 - v_t)})
                self.oracle_lines.append(line)
        else:
            rej = sorted((out / "scenes" / ".rejected").glob("*.json"))
            if rej:
                self.rejected.append(rejected_record(json.loads(rej[0].read_text())) or {})
                line["why"] = self.rejected[-1].get("why")
            else:
                self.failed.append({"seed": seed, "error": str(outcome.error)[:300]})
        print(json.dumps(line), file=sys.stderr, flush=True)

    def result(self) -> dict[str, Any]:
        from mixcount.evaluate.count_stats import summarise_counts

        args, n = self.args, max(len(self.rows), 1)
        out: dict[str, Any] = {
            "bench": "counts", "run": self.label, "counts": self.counts, "pool": args.pool,
            "resolution": args.resolution, "samples": args.samples, "scenes_kept": len(self.rows),
            "seeds": f"{args.seed}-{self.seed - 1}", "seconds_per_kept_scene": round(self.seconds / n, 2),
            "physics_s_per_scene": round(self.physics / n, 2), "rgb_s_per_scene": round(self.rgb / n, 2),
            "worker_peak_mb": _worker_peak_mb(self.worker), "failed": self.failed}
        if self.dist.is_paper:
            kept = sorted(r["kept"] for r in self.rows)
            out.update({"kept_median": kept[len(kept) // 2] if kept else None, "kept_range": [kept[0], kept[-1]]
                        if kept else None, "regenerated": len(self.rejected)})
        else:
            out.update(summarise_counts(self.rows, self.rejected, target_cdf=self.dist.cdf))
        out.update(look_summary(self.looks))
        if self.oracle_lines:
            out["oracle"] = self.oracle_lines
        return out


def look_summary(lines: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians of the kept scenes' look (:func:`scene_look`) and the worker CPU seconds per kept scene."""
    import numpy as np

    def med(key: str) -> Optional[float]:
        v = [float(ln[key]) for ln in lines if ln.get(key) is not None]
        return round(float(np.median(v)), 4) if v else None

    cpu = [float(ln["worker_cpu_s"]) for ln in lines if ln.get("worker_cpu_s") is not None]
    return {"image_share_median": med("image_share"), "visible_px_median": med("visible_px_median"),
            "union_box_median": med("union_box"), "luminance_median": med("luminance"),
            "reframe_distance_ratio_median": med("reframe_distance_ratio"), "reframe_shift_median": med("reframe_shift"),
            "worker_cpu_s_per_kept_scene": round(sum(cpu) / len(cpu), 2) if cpu else None}


def summarise_logs(logs: list[Path], work: Path, counts: str) -> list[dict[str, Any]]:
    """The figures of runs already made (several runs' stderr logs, e.g. one stopped and one continued),
    from their per-scene lines and the scene folders under ``work``: one result per run label, then the
    time ratio when the paper's rule ran too (over the seeds both runs kept)."""
    from mixcount.counts.targets import parse_count_target
    from mixcount.evaluate.count_stats import rejected_record, scene_record, summarise_counts

    lines = [json.loads(ln) for log in logs for ln in log.read_text().splitlines()
             if ln.startswith('{"bench": "counts.scene"')]
    out = []
    by_label: dict[str, dict[int, dict[str, Any]]] = {}
    for ln in lines:
        by_label.setdefault(ln["run"], {})[int(ln["seed"])] = ln
    for label, scenes in by_label.items():
        rows, rejected = [], []
        for seed, ln in sorted(scenes.items()):
            folder = work / f"out_{label}" / f"seed_{seed}" / "scenes"
            if ln["status"] == "written":
                meta = json.loads(next(folder.glob("scene_*/metadata.json")).read_text())
                rows.append(scene_record(meta) if label != "paper" else {"kept": meta["n_counted"]})
            else:
                rej = sorted((folder / ".rejected").glob("*.json"))
                if rej:
                    rejected.append(rejected_record(json.loads(rej[0].read_text())) or {})
        kept_lines = [ln for ln in scenes.values() if ln["status"] == "written"]
        n = max(len(kept_lines), 1)
        res: dict[str, Any] = {
            "bench": "counts", "run": label, "scenes_kept": len(kept_lines), "seeds": f"{min(scenes)}-{max(scenes)}",
            "seconds_per_kept_scene": round(sum(ln["seconds"] for ln in scenes.values()) / n, 2),
            "scene_seconds_median": sorted(ln["seconds"] for ln in kept_lines)[len(kept_lines) // 2] if kept_lines else None,
            "physics_s_per_scene": round(sum(ln.get("physics_s") or 0 for ln in kept_lines) / n, 2),
            "rgb_s_per_scene": round(sum(ln.get("rgb_s") or 0 for ln in kept_lines) / n, 2)}
        if label == "paper":
            kept = sorted(r["kept"] for r in rows)
            res.update({"kept_median": kept[len(kept) // 2] if kept else None, "regenerated": len(rejected)})
        else:
            res.update({k: v for k, v in summarise_counts(rows, rejected, target_cdf=parse_count_target(counts).cdf)
                        .items() if k != "imbalance"})
        res.update(look_summary(kept_lines))
        out.append(res)
    if "paper" in by_label and len(by_label) == 2:
        other = next(v for k, v in by_label.items() if k != "paper")
        both = sorted(set(other) & set(by_label["paper"]))
        t_target = sum(other[s]["seconds"] for s in both)
        t_paper = sum(by_label["paper"][s]["seconds"] for s in both)
        out.append({"bench": "counts.time_ratio", "seeds_both_ran": len(both),
                    "target_over_paper": round(t_target / max(t_paper, 1e-9), 3)})
    if "paper" in by_label and len(by_label) == 2:  # per kept scene, the regenerated seeds' time included
        per = {k: (sum(ln["seconds"] for ln in v.values()), sum(ln.get("worker_cpu_s") or 0 for ln in v.values()),
                   max(sum(1 for ln in v.values() if ln["status"] == "written"), 1)) for k, v in by_label.items()}
        t, p = next(v for k, v in per.items() if k != "paper"), per["paper"]
        out.append({"bench": "counts.time_ratio_per_kept_scene", "wall": round(t[0] / t[2] / max(p[0] / p[2], 1e-9), 3),
                    "worker_cpu": round(t[1] / t[2] / max(p[1] / p[2], 1e-9), 3) if p[1] else None})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--counts", default="uniform:1-200", help="the count target (scene.count_target)")
    ap.add_argument("--pool", choices=("light", "heavy"), default="heavy")
    ap.add_argument("--scenes", type=int, default=60, help="scenes to keep")
    ap.add_argument("--seed", type=int, default=100, help="first seed")
    ap.add_argument("--paper", action="store_true", help="also run the paper's rule on the same number of scenes")
    ap.add_argument("--paper-scenes", type=int, default=0, help="the paper's rule stops after this many (0: --scenes)")
    ap.add_argument("--oracle", action="store_true", help="the reference check (one render per object)")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2, help="Cycles threads")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per scene")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override (repeatable)")
    ap.add_argument("--budget-s", type=float, default=0, help="stop after this many seconds (0: never), "
                    "figures of the scenes kept by then")
    ap.add_argument("--write-coco", type=Path, default=None, metavar="PATH",
                    help="after the runs, merge the first run's scenes' coco.json (cam_0) into one COCO file: "
                    "the paper run's own histogram for a later --counts histogram:PATH")
    ap.add_argument("--work", type=Path, default=None, help="pools, assets and scenes (reused across runs)")
    ap.add_argument("--smoke", action="store_true", help="seconds: tiny sizes, same code path (the suite runs it)")
    ap.add_argument("--summarise", type=Path, nargs="*", default=None, metavar="LOG",
                    help="print the figures of runs already made from their stderr logs and --work's scene folders")
    args = ap.parse_args()
    if args.summarise:
        for res in summarise_logs(args.summarise, args.work, args.counts):
            print(json.dumps(res), flush=True)
        return 0
    if args.smoke:  # two light-pool scenes of 3-8 visible objects at 32 px, 1 sample, 60 frames; the paper's too
        args.pool, args.scenes, args.resolution, args.samples, args.threads = "light", 2, 32, 1, 1
        args.paper = True
        args.counts = "uniform:3-8,imbalance:1-2"
        args.set = [*args.set, "compose.denoise=false", "scene.physics_frames=60", "scene.n_classes=[1, 2]", "scene.n_distractors=[0, 1]",
                    "scene.n_objects=[6, 14]"]

    from pools import load_pool

    from mixcount.worker.client import BlenderWorker

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-counts-"))
    pool = load_pool(args.pool, work)
    t0 = time.perf_counter()
    label = "paper" if args.counts == "paper" else args.counts.replace(":", "_").replace(",", "_").replace("/", "_")[-60:]
    with contextlib.ExitStack() as stack:
        runs = []
        for counts, name in [(args.counts, label)] + ([("paper", "paper")] if args.paper else []):
            worker = stack.enter_context(BlenderWorker(name=f"bench-counts-{name}", log_dir=work))
            worker.request({"op": "ping"}, timeout=300)
            runs.append(Run(counts, args, work, worker, pool, name))
        while not all(r.done for r in runs):  # alternate: both runs see the same load on the machine
            if args.budget_s and time.perf_counter() - t0 > args.budget_s:
                print(f"bench/counts.py: --budget-s {args.budget_s} spent: figures of the scenes so far",
                      file=sys.stderr)
                break
            for r in runs:
                if not r.done:
                    r.step()
        results = [r.result() for r in runs]
        if args.write_coco:
            dirs = [Path(ln["path"]) for ln in runs[0].looks]
            print(f"bench/counts.py: wrote {write_coco(dirs, args.write_coco)} images to {args.write_coco}",
                  file=sys.stderr)
    for res in results:
        print(json.dumps(res), flush=True)
    if len(results) == 2:
        ratio = results[0]["seconds_per_kept_scene"] / max(results[1]["seconds_per_kept_scene"], 1e-9)
        print(json.dumps({"bench": "counts.time_ratio", "target_over_paper": round(ratio, 3)}), flush=True)
    print(f"bench/counts.py: {time.perf_counter() - t0:.1f} s, own peak {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
