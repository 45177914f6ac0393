"""Curation: canonical renders, descriptors, duplicate/degenerate/outlier flags, review, contact sheets."""
