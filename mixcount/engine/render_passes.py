"""Cycles render settings and render passes (bpy; runs only inside the worker process).

Two kinds of render, both on the same pixel grid:

* the *id pass* render: 1 sample, a 0.01 px box filter, no bounces, no denoising; Cycles then samples
  every pixel at its centre, so the object-index pass holds exact integer ids and the depth / normal
  passes are those of the surface seen through the pixel centre. It renders unlit (lamps and world
  off for the render): the passes read only the first hit's object, distance and shading normal, which
  no light changes, and Cycles would otherwise still trace a shadow ray and sample the world at every
  pixel (~0.6-0.8 s of a 1024² id pass on a heavy scene, docs/performance.md). It writes a multi-layer EXR
  (``render.image_settings.media_type = 'MULTI_LAYER_IMAGE'``; Blender 5.0 dropped the
  OPEN_EXR_MULTILAYER format enum from the usual path) read back with the ``OpenEXR`` package.
* the *RGB* render: the configured samples and denoiser, the default 1.5 px Blackman-Harris filter,
  written as an 8-bit PNG.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence

import numpy as np

# layer names in Blender 5.0's multi-layer EXR: "<ViewLayer>.<Pass>" with channels R/G/B/A/V/X/Y/Z
PASS_INDEX = "Object Index"
PASS_DEPTH = "Depth"
PASS_NORMAL = "Normal"


def configure_common(scene: Any, *, threads: int) -> None:
    """Cycles on the worker's device (the CPU unless ``compose.device`` asked for a GPU,
    :mod:`mixcount.engine.devices`) with a fixed seed and a capped number of render threads."""
    from mixcount.engine import devices

    scene.render.engine = "CYCLES"
    devices.apply(scene)
    scene.cycles.seed = 0
    scene.cycles.use_animated_seed = False
    scene.cycles.use_adaptive_sampling = False
    if threads > 0:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = int(threads)
    else:
        scene.render.threads_mode = "AUTO"
    scene.render.resolution_percentage = 100
    scene.render.use_persistent_data = False
    scene.render.film_transparent = False


def configure_id_pass(scene: Any) -> None:
    """Exact per-pixel ids, depth and normals: 1 sample at the pixel centre, direct hits only."""
    c = scene.cycles
    c.samples = 1
    c.use_denoising = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 0.01
    c.max_bounces = 0
    c.diffuse_bounces = 0
    c.glossy_bounces = 0
    c.transmission_bounces = 0
    c.transparent_max_bounces = 0
    vl = scene.view_layers[0]
    vl.use_pass_combined = False  # never read from the id pass
    vl.use_pass_object_index = True
    vl.use_pass_z = True
    vl.use_pass_normal = True
    s = scene.render.image_settings
    s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    s.exr_codec = "NONE"  # a temporary file read back at once: ZIP cost ~0.3-0.5 s a render at 1024²


IMAGE_NODES = ("ShaderNodeTexImage", "ShaderNodeTexEnvironment")


def missing_images(scene: Any) -> list[str]:
    """Every image texture the scene's objects and world sample that has no pixels to give: Cycles renders
    those flat magenta without a word. Blender's USD importer drops a texture file it cannot open (only
    its log says "Couldn't open image file"), leaving the node empty; an image whose file went away after
    loading keeps its path. One line each, naming the material and the file where known."""
    import bpy

    owners: dict[str, Any] = {}
    for obj in scene.objects:
        for slot in getattr(obj, "material_slots", ()):
            if slot.material is not None and slot.material.node_tree is not None:
                owners[f"material {slot.material.name!r}"] = slot.material.node_tree
    if scene.world is not None and scene.world.node_tree is not None:
        owners[f"world {scene.world.name!r}"] = scene.world.node_tree
    out = []
    for owner, tree in sorted(owners.items()):
        for node in tree.nodes:
            if node.bl_idname not in IMAGE_NODES:
                continue
            img = node.image
            if img is None:
                out.append(f"{owner}: texture node {node.name!r} has no image (its file could not be opened)")
            elif img.source == "FILE" and img.packed_file is None and not os.path.isfile(bpy.path.abspath(img.filepath)):
                out.append(f"{owner}: image file {bpy.path.abspath(img.filepath)} is missing")
    return out


def require_images(scene: Any) -> None:
    """AssetError (one line, the first of :func:`missing_images`) instead of a magenta render."""
    from mixcount.errors import AssetError

    bad = missing_images(scene)
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise AssetError(f"{bad[0]}{more}: nothing rendered (Blender would paint it magenta)")


def configure_rgb(scene: Any, render: Any) -> dict[str, Any]:
    """The final image with a :class:`~mixcount.scene.spec.RenderSpec`'s settings: samples, denoiser and
    every :class:`~mixcount.scene.spec.CyclesSpec` field; returns what Cycles holds afterwards, read back
    (recorded beside the spec in the scene's diagnostics).

    ``denoise_prefilter`` is OIDN's treatment of the albedo / normal guiding passes. ACCURATE (Blender's
    default) denoises them first, i.e. runs the network three times: 13.4 s of a 1024² render on 2 cores;
    FAST (guides denoised with the colour) 2.3 s (docs/performance.md). A texture without pixels stops it
    first (:func:`require_images`)."""
    require_images(scene)
    c, cy = scene.cycles, render.cycles
    c.samples = int(render.samples)
    c.use_denoising = bool(render.denoise)
    if render.denoise:
        c.denoiser = "OPENIMAGEDENOISE"
        c.denoising_prefilter = render.denoise_prefilter
        c.denoising_quality = cy.denoising_quality
    c.use_adaptive_sampling = cy.adaptive_threshold > 0
    if cy.adaptive_threshold > 0:
        c.adaptive_threshold = float(cy.adaptive_threshold)
        c.adaptive_min_samples = int(cy.adaptive_min_samples)
    for name in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces",
                 "transparent_max_bounces", "volume_bounces"):
        setattr(c, name, int(getattr(cy, name)))
    c.use_light_tree = bool(cy.light_tree)
    c.caustics_reflective = bool(cy.caustics_reflective)
    c.caustics_refractive = bool(cy.caustics_refractive)
    c.blur_glossy = float(cy.blur_glossy)
    c.sample_clamp_direct = float(cy.sample_clamp_direct)
    c.sample_clamp_indirect = float(cy.sample_clamp_indirect)
    c.texture_limit_render = cy.texture_limit
    c.pixel_filter_type = cy.pixel_filter
    c.filter_width = float(cy.filter_width)
    c.sampling_pattern = cy.sampling_pattern
    world = scene.world
    if world is not None:  # the environment light's importance map
        world.cycles.sampling_method = cy.world_sampling
        world.cycles.sample_map_resolution = int(cy.world_map_resolution)
    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    vl.use_pass_object_index = False
    vl.use_pass_z = False
    vl.use_pass_normal = False
    s = scene.render.image_settings
    s.media_type = "IMAGE"
    s.file_format = "PNG"
    s.color_mode = "RGB"
    s.color_depth = "8"
    applied = {name: _plain(getattr(c, name)) for name in RGB_READBACK}
    if world is not None:
        applied.update(world_sampling_method=str(world.cycles.sampling_method),
                       world_sample_map_resolution=int(world.cycles.sample_map_resolution))
    return applied


# scene.cycles properties read back after configure_rgb (what the RGB render really used)
RGB_READBACK = ("samples", "use_denoising", "denoiser", "denoising_prefilter", "denoising_quality",
                "use_adaptive_sampling", "adaptive_threshold", "adaptive_min_samples", "max_bounces",
                "diffuse_bounces", "glossy_bounces", "transmission_bounces", "transparent_max_bounces",
                "volume_bounces", "use_light_tree", "caustics_reflective", "caustics_refractive", "blur_glossy",
                "sample_clamp_direct", "sample_clamp_indirect", "texture_limit_render", "pixel_filter_type",
                "filter_width", "seed", "sampling_pattern")


def _plain(value: Any) -> Any:
    return round(value, 6) if isinstance(value, float) else value


def render_to(scene: Any, path: Path) -> None:
    import bpy

    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if not Path(path).exists():
        raise RuntimeError(f"Blender wrote no file at {path}")


def read_exr_layers(path: Path) -> dict[str, np.ndarray]:
    """Every layer of a multi-part / multi-layer EXR as float32 arrays: name -> (H, W) or (H, W, C).

    Keys are the pass names without the view-layer prefix ("Object Index", "Depth", "Normal", ...).
    """
    import OpenEXR

    layers: dict[str, dict[str, np.ndarray]] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                layer, _, comp = name.rpartition(".")
                # "ViewLayer.Object Index.X" -> layer "ViewLayer.Object Index", comp "X"
                key = layer.split(".", 1)[1] if "." in layer else layer
                layers.setdefault(key, {})[comp] = np.asarray(ch.pixels, dtype=np.float32)
    out: dict[str, np.ndarray] = {}
    for key, chans in layers.items():
        order = [c for c in ("R", "G", "B", "A", "X", "Y", "Z", "V") if c in chans] or sorted(chans)
        arrs = [chans[c] for c in order]
        out[key] = arrs[0] if len(arrs) == 1 else np.stack(arrs, axis=-1)
    return out


class _Unlit:
    """Lamps hidden from the render and no world for the duration of a ``with`` block; both restored.

    Re-entrant: inside an outer block (a series of id passes, :func:`id_pass_series`) there is nothing
    left to switch off, so an inner one changes nothing. Swapping the world out and back costs a heavy
    scene ~0.7 s of Cycles re-sync even with persistent data (docs/blender.md)."""

    def __init__(self, scene: Any) -> None:
        self.scene = scene

    def __enter__(self) -> None:
        self.world = self.scene.world
        self.lamps = [o for o in self.scene.objects if o.type == "LIGHT" and not o.hide_render]
        for o in self.lamps:
            o.hide_render = True
        if self.world is not None:
            self.scene.world = None

    def __exit__(self, *exc: Any) -> None:
        if self.world is not None:
            self.scene.world = self.world
        for o in self.lamps:
            o.hide_render = False


TWIN_SUFFIX = "~twin"  # the name suffix of :func:`_instanced_twins`' objects


@contextlib.contextmanager
def _instanced_twins(scene: Any) -> Iterator[None]:
    """Every mesh that one labelled rendered object alone uses (a distractor's, the container's; the floor,
    pass index 0, is a few faces and is left as it is) gets a second user for the block: a twin object
    beyond every camera's far clip (no camera ray reaches it, and an id pass traces camera rays only).

    Cycles bakes the transform of single-user geometry into its vertices and rebuilds that geometry's
    BVH whenever anything in the scene changes: with a few capture distractors (each its own mesh of
    200k-800k faces) every re-render after a drop or a move cost 0.5-1.5 s of the 128 px id pass, against
    0.03 s once each had a twin (bpy 5.0.1, docs/blender.md). Instanced geometry keeps its BVH and is
    intersected in object space: the ids are the same pixel for pixel, depth and normals to float
    precision (a few normals of a bumpy capture differ where a ray meets a shared edge)."""
    import bpy

    users: dict[Any, int] = {}
    for o in scene.objects:
        if o.type == "MESH" and not o.hide_render:
            users[o.data] = users.get(o.data, 0) + (1 if o.pass_index > 0 else 2)
    cams = [o for o in scene.objects if o.type == "CAMERA"]
    reach = max((float(np.linalg.norm(np.array(c.matrix_world.translation))) + float(c.data.clip_end)
                 for c in cams), default=1000.0)
    twins = []
    for k, (mesh, n) in enumerate(users.items()):
        if n != 1:
            continue
        twin = bpy.data.objects.new(f"{mesh.name[:40]}{TWIN_SUFFIX}", mesh)
        twin.location = (0.0, 0.0, -(2.0 * reach + 1000.0 + 100.0 * k))
        twin.pass_index = 0
        scene.collection.objects.link(twin)
        twins.append(twin)
    try:
        yield
    finally:
        for twin in twins:
            bpy.data.objects.remove(twin, do_unlink=True)


@contextlib.contextmanager
def id_pass_series(scene: Any) -> Iterator[None]:
    """A series of id-pass renders: lamps and world off once for the whole block (:class:`_Unlit`),
    and Cycles' synced scene (geometry, BVH) kept from one render to the next
    (``render.use_persistent_data``); both undone afterwards, so the next render outside starts fresh.

    The visibility loop's re-renders differ from the render before only by the objects it dropped;
    without this each one re-synced the whole heavy scene (docs/performance.md, "Container heaps: the
    time outside the render cut"). Single-user meshes get a twin beyond the far clip for the block
    (:func:`_instanced_twins`), so a change elsewhere does not rebuild them. The RGB render runs outside
    the block, as before. Re-entrant: a series inside a series changes nothing (the outer one keeps
    persistent data on, the world and lamps off and the twins until it ends)."""
    r = scene.render
    before = r.use_persistent_data
    if not before:  # (turning it off frees Cycles' synced scene: an inner series leaves it alone)
        r.use_persistent_data = True
    try:
        with _Unlit(scene), _instanced_twins(scene):
            yield
    finally:
        if not before:
            r.use_persistent_data = False


def region_window(region: tuple[int, int, int, int], width: int, height: int) -> tuple[float, float, float, float]:
    """Pixel rows/columns ``(row0, col0, row1, col1)`` (inclusive, top-down) -> Blender's normalised border
    ``(min_x, max_x, min_y, max_y)`` (y from the bottom), with one pixel of slack on each side."""
    row0, col0, row1, col1 = region
    return (max(0.0, (col0 - 1) / width), min(1.0, (col1 + 2) / width),
            max(0.0, (height - row1 - 2) / height), min(1.0, (height - row0 + 1) / height))


@contextlib.contextmanager
def border(scene: Any, window: Optional[Sequence[float]]) -> Iterator[None]:
    """Render only the normalised ``window`` ``(min_x, max_x, min_y, max_y)`` inside this block (not
    cropped: the image keeps its size, pixels outside are undefined); ``None`` renders the whole frame."""
    r = scene.render
    if window is None:
        yield
        return
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = (float(b) for b in window)
    r.use_border, r.use_crop_to_border = True, False
    try:
        yield
    finally:
        r.use_border = False


def render_id_passes(scene: Any, path: Path, region: Optional[tuple[int, int, int, int]] = None,
                     unlit: bool = True) -> dict[str, np.ndarray]:
    """Render the id pass and return ``index`` (int32), ``depth`` (float32, metres along the view ray
    as Cycles reports it, background 1e10) and ``normal`` (world space) arrays, rows top-down.

    ``region`` = (row0, col0, row1, col1), inclusive, top-down: render only a border around those pixels
    (``render.use_border``, not cropped). Pixels inside the region are exactly those of a full render
    (each pixel is one ray through its centre; checked in tests/test_blender_worker.py); pixels outside
    it are undefined, so the caller takes the region alone (:func:`mixcount.scene_decisions.paste_region`).
    """
    configure_id_pass(scene)
    r = scene.render
    window = None if region is None else region_window(region, r.resolution_x, r.resolution_y)
    with border(scene, window), (_Unlit(scene) if unlit else contextlib.nullcontext()):
        render_to(scene, path)
    layers = read_exr_layers(path)
    missing = [k for k in (PASS_INDEX, PASS_DEPTH, PASS_NORMAL) if k not in layers]
    if missing:
        raise RuntimeError(f"EXR {path} lacks passes {missing}; has {sorted(layers)}")
    index = layers[PASS_INDEX]
    if index.ndim == 3:
        index = index[..., 0]
    depth = layers[PASS_DEPTH]
    if depth.ndim == 3:
        depth = depth[..., 0]
    normal = layers[PASS_NORMAL][..., :3]
    return {"index": np.rint(index).astype(np.int32), "index_raw": index, "depth": depth.astype(np.float32),
            "normal": normal.astype(np.float32)}


def remove_quiet(path: Path) -> None:
    try:
        os.remove(path)
    except OSError:
        pass
