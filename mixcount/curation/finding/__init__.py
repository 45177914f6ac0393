"""Finding flags (`catalog filter`): from each object's descriptors to duplicate, look-alike and quality
flags and the object statuses they decide (``catalog_filter.run_filter``; see docs/curation.md)."""
