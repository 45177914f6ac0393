"""mixcount: photorealistic mixed-object counting datasets from a catalog of real 3D captures.

`import mixcount` stays light: it never imports bpy, pxr or trimesh. Engines are imported by the
modules that need them (``mixcount.blender`` runs bpy in worker processes only).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mixcount")  # one source of truth: pyproject.toml
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
