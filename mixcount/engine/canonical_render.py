"""Canonical white-background renders of one catalog object (bpy; runs only inside the worker process).

One render = factory-empty scene -> ``import_scene.gltf`` (or another importer by file type) -> the
object's world bounding box centred on the origin -> an orthographic camera at a fixed elevation and
azimuth, framed on the projected vertices with a margin -> Cycles on the CPU, a white world of moderate
strength as even fill light plus one soft sun -> RGBA PNG with a transparent film, composited onto pure
white in numpy, so background pixels are exactly (255, 255, 255) whatever the view transform does.

Orthographic framing on the projected vertices makes the render scale-free: the same shape at twice the
size gives the same picture, which is what the appearance check and a rescaled duplicate rely on.

Vertex colours: Blender's OBJ and PLY importers (and a glTF without a material) store a model's vertex
colours as a colour attribute but give the mesh no material, so Cycles would render it in the default
white-grey. :func:`use_vertex_colours` gives such a mesh a Principled material whose base colour is that
attribute, as the scene render does through the USD asset's ``displayColor`` (mixcount.usd.assets), so an
external exemplar has the colour of the object it stands for.

Frame: Blender's importers each assume an up axis (glTF and OBJ Y-up, PLY and STL Z-up, USD its own);
the catalog may read the file with another one (``metadata.json`` ``up_axis``, ``ingest --up-axis``,
``ingest.assume_up_axis``). :func:`orient_to_catalog` turns the import into the catalog's frame (the
request's ``up_axis``), so the canonical render shows the object standing as the scenes place it.

Outputs per view: ``<stem>.png`` (RGB on white), ``<stem>_mask.png`` (8-bit coverage, the film alpha) and
``<stem>_albedo.png`` (the surface colour without shading, :func:`render_albedo`).

Heavy models (more triangles than ``canonical_render.heavy_faces``: the catalog decides by the face count
its render rows are hashed with and says so in the request's ``heavy``; a request without it is counted on
the imported meshes by :func:`triangle_count`): the albedo's colour passes ride along with the RGB render
and are read from its render result (:func:`save_colour_passes`) instead of a second render of the scene, and OIDN's prefilter is
``heavy_denoise_prefilter`` (FAST) instead of Blender's ACCURATE. On a 1.2 M-face capture with 4K textures
the second render costs ~3.4 s a view and the ACCURATE prefilter ~7 CPU-s (docs/performance.md). Models at
or under the threshold take exactly the code path they always did: their files do not change.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.engine.render_passes import require_images
from mixcount.worker.canonical_contract import CANONICAL, CanonicalRequest, CanonicalResult, CanonicalView

IMPORTERS = {
    ".glb": "gltf", ".gltf": "gltf", ".obj": "obj", ".ply": "ply", ".stl": "stl",
    ".usd": "usd", ".usda": "usda", ".usdc": "usd", ".usdz": "usd",
}


def reset_scene() -> Any:
    """A factory-empty file: no objects, materials or images left from the previous object."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def import_model(path: Path) -> list[Any]:
    """Import one model file; returns its mesh objects (raises RuntimeError when there are none)."""
    import bpy

    kind = IMPORTERS.get(path.suffix.lower())
    if kind is None:
        raise RuntimeError(f"unsupported model format {path.suffix or '(none)'}")
    before = set(bpy.data.objects)
    if kind == "gltf":
        res = bpy.ops.import_scene.gltf(filepath=str(path))
    elif kind == "obj":
        res = bpy.ops.wm.obj_import(filepath=str(path))
    elif kind == "ply":
        res = bpy.ops.wm.ply_import(filepath=str(path))
    elif kind == "stl":
        res = bpy.ops.wm.stl_import(filepath=str(path))
    else:
        res = bpy.ops.wm.usd_import(filepath=str(path), import_lights=False, import_cameras=False)
    if "FINISHED" not in res:
        raise RuntimeError(f"import of {path.name} failed: {sorted(res)}")
    meshes = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]
    if not meshes:
        raise RuntimeError(f"{path.name} holds no mesh")
    return meshes


IMPORTER_UP_AXIS = {"gltf": "Y", "obj": "Y", "ply": "Z", "stl": "Z"}  # Blender 5.0's defaults


def orient_to_catalog(path: Path, up_axis: str) -> bool:
    """Turn every imported root object from the importer's up axis to ``up_axis`` (X, Y or Z; "" or a USD
    file: left as imported). Returns whether it turned anything."""
    import bpy
    import mathutils

    from mixcount.frame import up_axis_rotation

    assumed = IMPORTER_UP_AXIS.get(IMPORTERS.get(path.suffix.lower(), ""), "")
    wanted = (up_axis or "").upper()
    if not assumed or not wanted or wanted == assumed:
        return False
    # the importer applied R(assumed) to the file's coordinates; the catalog applies R(wanted)
    turn = up_axis_rotation(wanted) @ up_axis_rotation(assumed).T
    m = mathutils.Matrix([[float(v) for v in row] + [0.0] for row in turn] + [[0.0, 0.0, 0.0, 1.0]])
    for obj in [o for o in bpy.data.objects if o.parent is None and o.type not in ("CAMERA", "LIGHT")]:
        obj.matrix_world = m @ obj.matrix_world
    bpy.context.view_layer.update()
    return True


def use_vertex_colours(objects: list[Any]) -> int:
    """Give every mesh that has a colour attribute and no material one whose base colour reads that
    attribute (the active colour, else the first); returns how many meshes got one. A mesh with a
    material keeps it: its material says how it looks (as in the USD asset, where a material wins)."""
    import bpy

    done = 0
    for obj in objects:
        mesh = obj.data
        colours = getattr(mesh, "color_attributes", None)
        if not colours or any(slot.material is not None for slot in obj.material_slots):
            continue
        name = colours.active_color_name or colours[0].name
        mat = bpy.data.materials.new(f"vertex_colour_{obj.name}")
        mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
        attr = nodes.new("ShaderNodeVertexColor")
        attr.layer_name = name
        links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
        bsdf.inputs["Roughness"].default_value = 0.5
        mesh.materials.clear()
        mesh.materials.append(mat)
        done += 1
    return done


def _has_image_texture(obj: Any) -> bool:
    """True when a material of ``obj`` samples an image (a texture of its own, never a stand-in)."""
    for slot in obj.material_slots:
        tree = getattr(slot.material, "node_tree", None) if slot.material is not None else None
        if tree is not None and any(n.type == "TEX_IMAGE" and n.image is not None for n in tree.nodes):
            return True
    return False


def apply_look(objects: list[Any], look: Any, *, over_stand_ins: bool = False) -> int:
    """Give every mesh with no material, no colour attribute and no texture a Principled material of
    ``look`` = (sRGB r, g, b, metallic, roughness): an STL, PLY or OBJ-without-.mtl part would otherwise
    render in Cycles' default near-white, as the USD asset's part does not (:mod:`mixcount.usd.assets`).
    ``over_stand_ins``: the catalog read no colour in the model, so a material the importer made (an OBJ's
    ``usemtl`` whose .mtl is missing) is replaced too, unless it samples an image. Returns how many meshes
    got it."""
    import bpy

    from mixcount.catalog.materials import srgb_to_linear

    if look is None:
        return 0
    done, mat = 0, None
    for obj in objects:
        if obj.type != "MESH":
            continue
        has_material = any(slot.material is not None for slot in obj.material_slots)
        if has_material and (not over_stand_ins or _has_image_texture(obj)):
            continue
        if getattr(obj.data, "color_attributes", None):
            continue  # its own colours (use_vertex_colours gives them a material)
        if mat is None:
            mat = bpy.data.materials.new("palette_look")
            mat.use_nodes = True
            bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
            bsdf.inputs["Base Color"].default_value = (*[float(c) for c in srgb_to_linear(look[:3])], 1.0)
            bsdf.inputs["Metallic"].default_value = float(look[3])
            bsdf.inputs["Roughness"].default_value = float(look[4])
        obj.data.materials.clear()
        obj.data.materials.append(mat)
        done += 1
    return done


def world_vertices(objects: list[Any]) -> np.ndarray:
    """All evaluated vertices of ``objects`` in world space, (n, 3)."""
    import bpy

    depsgraph = bpy.context.evaluated_depsgraph_get()
    chunks = []
    for obj in objects:
        ev = obj.evaluated_get(depsgraph)
        mesh = ev.to_mesh()
        try:
            n = len(mesh.vertices)
            if n:
                co = np.empty(n * 3, dtype=np.float64)
                mesh.vertices.foreach_get("co", co)
                co = co.reshape(n, 3)
                m = np.array(ev.matrix_world, dtype=np.float64)
                chunks.append(co @ m[:3, :3].T + m[:3, 3])
        finally:
            ev.to_mesh_clear()
    if not chunks:
        raise RuntimeError("model has no vertices")
    pts = np.vstack(chunks)
    if not np.all(np.isfinite(pts)):
        raise RuntimeError("model has non-finite vertices")
    return pts


def centre_objects(objects: list[Any]) -> np.ndarray:
    """Parent every top-level imported object under an empty that moves the bbox centre to the origin;
    returns the centred world vertices."""
    import bpy

    pts = world_vertices(objects)
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    pivot = bpy.data.objects.new("canonical_pivot", None)
    bpy.context.scene.collection.objects.link(pivot)
    roots = {o for o in bpy.data.objects if o.parent is None and o is not pivot and o.type not in ("CAMERA", "LIGHT")}
    for obj in roots:
        mw = obj.matrix_world.copy()
        obj.parent = pivot
        obj.matrix_world = mw
    pivot.location = (-centre[0], -centre[1], -centre[2])
    bpy.context.view_layer.update()
    return pts - centre


def view_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector from the origin towards the camera (Z-up; azimuth 0 = -Y, the front, towards +X)."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])


def camera_basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera right and up vectors for a camera looking along ``-direction`` with world Z up."""
    fwd = -direction / np.linalg.norm(direction)
    right = np.cross(fwd, np.array([0.0, 0.0, 1.0]))
    if np.linalg.norm(right) < 1e-6:  # looking straight down/up
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    return right, up


def add_camera(pts: np.ndarray, *, elevation_deg: float, azimuth_deg: float, margin: float) -> Any:
    """Orthographic camera framing the projected points with ``margin`` (fraction of the frame) around."""
    import bpy
    import mathutils

    direction = view_direction(elevation_deg, azimuth_deg)
    right, up = camera_basis(direction)
    u, v = pts @ right, pts @ up
    cu, cv = (u.min() + u.max()) / 2, (v.min() + v.max()) / 2
    span = max(float(np.ptp(u)), float(np.ptp(v)), 1e-6)
    radius = float(np.linalg.norm(pts, axis=1).max())
    cam_data = bpy.data.cameras.new("canonical_camera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = span / max(1e-3, 1.0 - 2.0 * margin)
    cam_data.clip_start = radius * 0.01
    cam_data.clip_end = radius * 10.0
    cam = bpy.data.objects.new("canonical_camera", cam_data)
    bpy.context.scene.collection.objects.link(cam)
    target = right * cu + up * cv
    loc = target + direction * radius * 3.0
    cam.location = mathutils.Vector(loc.tolist())
    basis = mathutils.Matrix((right.tolist(), up.tolist(), direction.tolist())).transposed()  # columns x, y, z
    cam.rotation_euler = basis.to_euler()
    bpy.context.scene.camera = cam
    return cam


def add_lighting(scene: Any, *, world_strength: float, sun_strength: float, azimuth_deg: float) -> None:
    """White world (even fill from every side) plus a soft sun from above, left of the camera."""
    import bpy

    world = bpy.data.worlds.new("canonical_world")
    world.use_nodes = True
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bg.inputs["Strength"].default_value = float(world_strength)
    scene.world = world
    if sun_strength > 0:
        sun_data = bpy.data.lights.new("canonical_sun", type="SUN")
        sun_data.energy = float(sun_strength)
        sun_data.angle = math.radians(30.0)  # wide sun disc: soft shadow edges
        sun = bpy.data.objects.new("canonical_sun", sun_data)
        sun.rotation_euler = (math.radians(35.0), 0.0, math.radians(azimuth_deg - 45.0))
        scene.collection.objects.link(sun)


def configure_render(scene: Any, *, resolution: int, samples: int, denoise: bool, threads: int) -> None:
    """Cycles on the CPU, fixed seed, transparent film, Standard view transform (colours as authored)."""
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = max(1, int(samples))
    c.seed = 0
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = bool(denoise)
    if denoise:
        c.denoiser = "OPENIMAGEDENOISE"
    c.max_bounces = 6
    c.transparent_max_bounces = 8
    scene.render.film_transparent = True
    scene.render.resolution_x = int(resolution)
    scene.render.resolution_y = int(resolution)
    scene.render.resolution_percentage = 100
    if threads > 0:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = int(threads)
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    s = scene.render.image_settings
    s.file_format = "PNG"
    s.color_mode = "RGBA"
    s.color_depth = "8"


def composite_on_white(rgba_path: Path, out_path: Path, mask_path: Path) -> dict[str, Any]:
    """Alpha-composite the transparent render onto pure white (numpy), write RGB and the coverage mask."""
    from PIL import Image

    with Image.open(rgba_path) as im:
        arr = np.asarray(im.convert("RGBA"), dtype=np.float64)
    alpha = arr[..., 3:4] / 255.0
    rgb = arr[..., :3] * alpha + 255.0 * (1.0 - alpha)  # straight (unassociated) alpha in Blender's PNG
    rgb = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    rgb[arr[..., 3] == 0] = 255
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out_path) as tmp:
        Image.fromarray(rgb, "RGB").save(tmp)
    with atomic_path(mask_path) as tmp:
        Image.fromarray(arr[..., 3].astype(np.uint8), "L").save(tmp)
    coverage = float((arr[..., 3] > 127).mean())
    return {"coverage": round(coverage, 6), "width": int(rgb.shape[1]), "height": int(rgb.shape[0])}


ALBEDO_PASSES = ("Diffuse Color", "Glossy Color", "Transmission Color")
ALBEDO_SAMPLES = 4  # the passes are the first hit's surface colour: samples only anti-alias the edges


def render_albedo(scene: Any, raw: Path, out: Path, mask_path: Path) -> None:
    """The surface colour the render shaded, without the shading: Cycles' diffuse + glossy + transmission
    colour passes (a Principled surface's base colour splits into them by metallic and transmission, so
    their sum is its albedo whatever the light), sRGB-encoded, as RGBA with the render's coverage mask as
    alpha, at ``out``. The captions name colours from it (:mod:`mixcount.captions.colours`); the render
    itself is unchanged. Render settings are restored afterwards. A second render of the scene (4 samples,
    no bounces): the light path; a heavy model reads the passes of its RGB render (:func:`save_colour_passes`)."""
    import bpy

    from mixcount.engine.render_passes import read_exr_layers

    c, vl, s = scene.cycles, scene.view_layers[0], scene.render.image_settings
    saved = (c.samples, c.use_denoising, c.max_bounces, s.media_type, s.file_format, s.color_mode, s.color_depth)
    c.samples, c.use_denoising, c.max_bounces = ALBEDO_SAMPLES, False, 0
    vl.use_pass_diffuse_color = vl.use_pass_glossy_color = vl.use_pass_transmission_color = True
    s.media_type, s.file_format, s.color_depth, s.exr_codec = "MULTI_LAYER_IMAGE", "OPEN_EXR_MULTILAYER", "32", "NONE"
    try:
        scene.render.filepath = str(raw)
        bpy.ops.render.render(write_still=True)
        layers = read_exr_layers(raw)
    finally:
        vl.use_pass_diffuse_color = vl.use_pass_glossy_color = vl.use_pass_transmission_color = False
        c.samples, c.use_denoising, c.max_bounces = saved[:3]
        s.media_type, s.file_format, s.color_mode, s.color_depth = saved[3:]
        raw.unlink(missing_ok=True)
    write_albedo(layers, out, mask_path)


def write_albedo(layers: dict[str, np.ndarray], out: Path, mask_path: Path) -> None:
    """The albedo PNG from the colour passes of a render (``layers``: :func:`read_exr_layers`): their sum,
    clipped to [0, 1], sRGB-encoded, with the coverage mask at ``mask_path`` as alpha."""
    from PIL import Image

    linear = sum(np.asarray(layers[name], dtype=np.float64)[..., :3] for name in ALBEDO_PASSES if name in layers)
    linear = np.clip(np.asarray(linear), 0.0, 1.0)
    srgb = np.where(linear <= 0.0031308, linear * 12.92, 1.055 * linear ** (1 / 2.4) - 0.055)
    alpha = np.asarray(Image.open(mask_path).convert("L"), dtype=np.uint8)
    rgba = np.dstack([np.round(srgb * 255).astype(np.uint8), alpha])
    with atomic_path(out) as tmp:
        Image.fromarray(rgba, "RGBA").save(tmp, format="PNG")


def triangle_count(objects: list[Any]) -> int:
    """Triangles of the imported meshes as Blender holds them (an n-gon counts n - 2: loops - 2 x polygons,
    no triangulation needed), the count ``heavy_faces`` is compared with; for a triangle mesh it is the
    catalog's ``face_count``."""
    total = 0
    for obj in objects:
        mesh = obj.data
        if obj.type == "MESH" and mesh is not None:
            total += max(0, len(mesh.loops) - 2 * len(mesh.polygons))
    return total


def configure_heavy(scene: Any, prefilter: str) -> None:
    """The heavy path's render settings: the diffuse / glossy / transmission colour passes on the view
    layer (the albedo, :func:`save_colour_passes`) and OIDN's prefilter ``prefilter``. The combined image
    does not depend on which passes are on; FAST denoises the guiding albedo / normal passes with the
    colour instead of on their own (two network runs fewer)."""
    vl = scene.view_layers[0]
    vl.use_pass_diffuse_color = vl.use_pass_glossy_color = vl.use_pass_transmission_color = True
    if scene.cycles.use_denoising:
        scene.cycles.denoising_prefilter = prefilter


def save_colour_passes(scene: Any, exr: Path) -> dict[str, np.ndarray]:
    """Every pass of the last render, read back: Blender's ``Render Result`` image saved as a 32-bit
    multilayer EXR (``Image.save_render`` writes all view-layer passes when the scene's output format is
    OPEN_EXR_MULTILAYER; bpy gives no pixel access to a render result), then :func:`read_exr_layers`.
    The scene's output settings are restored and the EXR removed."""
    import bpy

    from mixcount.engine.render_passes import read_exr_layers

    result = next((im for im in bpy.data.images if im.type == "RENDER_RESULT"), None)
    if result is None:
        raise RuntimeError("Blender kept no render result")
    s = scene.render.image_settings
    saved = (s.media_type, s.file_format, s.color_mode, s.color_depth)
    s.media_type, s.file_format, s.color_depth, s.exr_codec = "MULTI_LAYER_IMAGE", "OPEN_EXR_MULTILAYER", "32", "NONE"
    try:
        result.save_render(str(exr), scene=scene)
        layers = read_exr_layers(exr)
    finally:
        s.media_type, s.file_format, s.color_mode, s.color_depth = saved
        exr.unlink(missing_ok=True)
    missing = [name for name in ALBEDO_PASSES if name not in layers]
    if missing:
        raise RuntimeError(f"the render result holds no {', '.join(missing)} pass")
    return layers


def render_object(req: CanonicalRequest) -> CanonicalResult:
    """Render every view of one request (:meth:`CanonicalRequest.views`), each composited on white."""
    import bpy

    out_dir = Path(req.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = reset_scene()
    objects = import_model(Path(req.model_path))
    orient_to_catalog(Path(req.model_path), req.up_axis)
    use_vertex_colours(objects)
    apply_look(objects, req.look, over_stand_ins=req.stand_in_materials)
    require_images(scene)  # a texture its importer could not open: an error naming it, not magenta
    pts = centre_objects(objects)
    look = req.settings
    configure_render(scene, resolution=look.resolution, samples=look.samples, denoise=look.denoise, threads=req.threads)
    faces = triangle_count(objects)
    heavy = faces > look.heavy_faces if req.heavy is None else bool(req.heavy)  # the catalog's say, if it said
    if heavy:
        configure_heavy(scene, look.heavy_denoise_prefilter)
    add_lighting(scene, world_strength=look.world_strength, sun_strength=look.sun_strength, azimuth_deg=look.azimuth_deg)
    results = []
    for view, az in req.views():
        cam = add_camera(pts, elevation_deg=look.elevation_deg, azimuth_deg=az, margin=look.margin)
        stem = req.stem if view == CANONICAL else f"{req.stem}_{view}"
        raw = out_dir / f".{stem}.raw.png"
        scene.render.filepath = str(raw)
        bpy.ops.render.render(write_still=True)
        if not raw.exists():
            raise RuntimeError("Cycles wrote no image")
        layers = save_colour_passes(scene, out_dir / f".{stem}.passes.exr") if heavy else None
        out = out_dir / f"{stem}.png"
        mask = out_dir / f"{stem}_mask.png"
        info = composite_on_white(raw, out, mask)
        raw.unlink()
        if layers is not None:  # heavy: the albedo of the render just made
            write_albedo(layers, out_dir / f"{stem}_albedo.png", mask)
        else:
            render_albedo(scene, out_dir / f".{stem}.albedo.exr", out_dir / f"{stem}_albedo.png", mask)
        results.append(CanonicalView(view=view, path=str(out), mask_path=str(mask), **info))
        bpy.data.objects.remove(cam, do_unlink=True)
    return CanonicalResult(views=tuple(results), faces=faces, heavy=heavy)
