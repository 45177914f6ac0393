"""mixcount: photorealistic mixed-object counting datasets from a catalog of real 3D captures.

`import mixcount` stays light: it never imports bpy, pxr or trimesh. Engines are imported by the
modules that need them (``mixcount.engine`` runs bpy in worker processes only).

The Python API (:mod:`mixcount.api`, imported on first use)::

    import mixcount
    catalog = mixcount.open_catalog("catalog/catalog.db")
    mixcount.compose(catalog, "out/ds", n=4, split="train", config=["quick"])
    ds = mixcount.load_dataset("out/ds")
    for sample in ds.samples("train"):
        sample.image(), sample.boxes, sample.masks(), sample.points, sample.counts, sample.captions, sample.exemplars
"""

import importlib

API = ("open_catalog", "compose", "package", "load_dataset", "Dataset", "Sample", "Exemplar")
__all__ = ["__version__", *API]


def __getattr__(name: str):  # type: ignore[no-untyped-def]
    """The API names, imported from :mod:`mixcount.api` on first use (PEP 562), and ``__version__``
    (:mod:`mixcount.version`: one source of truth, pyproject.toml; read on first use)."""
    if name == "__version__":
        from mixcount.version import installed_version

        return installed_version()
    if name in API:
        return getattr(importlib.import_module("mixcount.api"), name)
    raise AttributeError(f"module 'mixcount' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *API])
