"""Count targets (issues 37 and 48): the number of *visible* counted objects a scene should keep, in one
engine-free room (numpy only, no bpy, no pxr).

- :mod:`mixcount.counts.targets`: ``--counts`` / ``[scene] count_target`` parsed, each scene's total and
  per-class split drawn by seed, the spawned and reserve counts the sampler sizes the scene with;
- :mod:`mixcount.counts.benchmark_files`: the counts read from a benchmark's own annotation file (COCO
  instances, FSC-147) for ``histogram:FILE.json``;
- :mod:`mixcount.counts.worker_decisions`: the decisions the bpy worker takes to bring a scene to its target
  (which surplus bodies may be taken out, where reserve bodies drop, whether the scene ended on target).

The engine-side steps that act on those decisions sit beside each other in the engine room:
:mod:`mixcount.engine.count_trim` (take out the surplus) and :mod:`mixcount.engine.count_topup` (the reserve,
the rest check, the top-up). docs/scene.md, "Count targets", walks through them in order.
"""
