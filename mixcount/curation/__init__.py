"""Curation, in two sub-rooms over two shared modules:

* ``finding/``: the automatic flags (`catalog filter`): descriptors, surface looks and their distances,
  candidate pairs, shape match, pair evidence, the copy / look / quality rules, the filter itself
  (``catalog_filter.run_filter``) and its check against a demo library's ground truth;
* ``review/``: a person's side (`catalog sheet`, `catalog review import`): the review page and contact
  sheets, the decisions file it exports, importing decisions and applying pair decisions.

Shared by both, here: ``renders.py`` (canonical renders) and ``flag_kinds.py`` (the flag kinds, their
severity and the marks in flag reasons). The two sub-rooms do not import each other.
"""
