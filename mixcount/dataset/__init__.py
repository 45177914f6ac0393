"""Dataset files: per-scene writer, streaming merge, and loaders of the stored passes."""

from mixcount.annotate.passes import read_depth, read_normals

__all__ = ["read_depth", "read_normals"]
