"""What a model file pulls in besides itself, and the cheap checks made before any mesh work.

``model_resources``: the buffers, materials and textures a model references, by reference name (hashed
into its content hash), with the pre-checks ingest makes before hashing (GLB header, missing files). A
missing glTF buffer or image is an error; an OBJ's missing material or texture is a warning (the model
loads with a default material), and a texture not where its material points is looked up by its file name
in the model's folder. ``relink_textures`` rewrites such materials so that the staged model finds them
(:func:`mixcount.catalog.layouts.discovery.stage`).
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import unquote

from mixcount.errors import IngestError

GLB_MAGIC = b"glTF"




def _is_external_uri(uri: str) -> bool:
    return bool(uri) and not uri.startswith("data:") and "://" not in uri


def _glb_json(path: Path) -> dict[str, Any]:
    """Parse a GLB header and its JSON chunk; raise a specific IngestError for a bad or short file."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(20)
        if len(head) < 12 or head[:4] != GLB_MAGIC:
            raise IngestError("not a GLB file: the first bytes are not the 'glTF' magic")
        version, declared = struct.unpack("<II", head[4:12])
        if version != 2:
            raise IngestError(f"unsupported GLB version {version} (only glTF 2.0)")
        if declared > size:
            raise IngestError(f"truncated GLB: header declares {declared} bytes, file has {size}")
        if len(head) < 20:
            raise IngestError("truncated GLB: no JSON chunk")
        chunk_len, chunk_type = struct.unpack("<II", head[12:20])
        if chunk_type != 0x4E4F534A:  # "JSON"
            raise IngestError("corrupt GLB: first chunk is not JSON")
        if 20 + chunk_len > size:
            raise IngestError(f"truncated GLB: JSON chunk of {chunk_len} bytes runs past the end of the file")
        try:
            return json.loads(fh.read(chunk_len))
        except ValueError as exc:
            raise IngestError(f"corrupt GLB: JSON chunk does not parse ({exc})") from None


def _gltf_resources(path: Path, doc: dict[str, Any]) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for kind, key in (("buffer", "buffers"), ("texture", "images")):
        for item in doc.get(key, []) or []:
            uri = item.get("uri", "") if isinstance(item, dict) else ""
            if not _is_external_uri(uri):
                continue
            ref = (path.parent / unquote(uri)).resolve()
            if not ref.is_file():
                raise IngestError(f"missing {kind} file: {uri}")
            out[unquote(uri)] = ref
    return out


_MTL_MAP = re.compile(r"^\s*(map_\w+|bump|disp|decal|norm)\s+(.+?)\s*$", re.IGNORECASE)


def _texture_file(tex: str, mtl: Path, model: Path) -> tuple[Path | None, bool]:
    """(file, found where the reference points) of an MTL texture reference: first where it points
    (relative to the MTL, ``../cube.png`` included), then by its file name in the model's folder (a
    Windows path such as ``E:\\data\\table.png`` too)."""
    ref = mtl.parent / tex
    if ref.is_file():
        return ref, True
    name = re.split(r"[\\/]", tex)[-1]
    for folder in dict.fromkeys((model.parent, mtl.parent)):
        if name and (folder / name).is_file():
            return folder / name, False
    return None, False


def missing_texture(tex: str, mtl_name: str) -> str:
    """The warning of a texture found neither where its material points nor by name."""
    return (f"missing texture file: {tex} (not where {mtl_name} points, nor by name in the folder; "
            "a default material is used)")


def _obj_resources(path: Path, warnings: list[str] | None) -> dict[str, Path]:
    """An OBJ's material files and textures. A missing one is no error: the model loads with a default
    material, as any viewer opens it; each miss is appended to ``warnings`` (or raises without a list)."""
    out: dict[str, Path] = {}
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise IngestError(f"cannot read model file: {exc.strerror}") from None

    def miss(message: str) -> None:
        if warnings is None:
            raise IngestError(message)
        warnings.append(message)

    for line in text.splitlines():
        if not line.startswith("mtllib"):
            continue
        name = line[len("mtllib"):].strip()
        if not name:
            continue
        mtl = path.parent / name
        if not mtl.is_file():
            miss(f"missing material file: {name} (a default material is used)")
            continue
        out[name] = mtl
        for mline in mtl.read_text(errors="replace").splitlines():
            match = _MTL_MAP.match(mline)
            if not match:
                continue
            tex = match.group(2).split()[-1]  # options such as "-bm 1" come first; the file is last
            ref, where = _texture_file(tex, mtl, path)
            if ref is None:
                miss(missing_texture(tex, name))
                continue
            if not where:
                miss(f"texture {tex} found by name in the folder, not where {name} points")
            out[tex] = ref
    return out


@dataclass
class Relinked:
    """An OBJ whose material names textures that are not where it points (found by name, or missing): the
    rewritten material files (by name) and the texture files they now name (by file name)."""

    materials: dict[str, str]
    textures: dict[str, Path]
    notes: list[str]


def relink_textures(path: Path) -> Relinked | None:
    """For an OBJ whose textures are found only by name (``../cube.png``, ``E:\\data\\table.png``) or not at
    all: its materials rewritten to name them by file name (a missing one left out, so that the model has
    its material's plain colour: Blender paints a missing image magenta), so that every loader (trimesh,
    Blender's importer) finds them when the model is staged beside them; None when nothing needs it."""
    if path.suffix.lower() != ".obj":
        return None
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return None
    out = Relinked({}, {}, [])
    moved = False
    for line in text.splitlines():
        if not line.startswith("mtllib"):
            continue
        name = line[len("mtllib"):].strip()
        mtl = path.parent / name
        if not name or not mtl.is_file():
            continue
        lines = []
        for mline in mtl.read_text(errors="replace").splitlines():
            match = _MTL_MAP.match(mline)
            if match:
                tex = match.group(2).split()[-1]
                ref, where = _texture_file(tex, mtl, path)
                if ref is None:  # dropped: Blender would paint a missing image magenta, not a default material
                    moved = True
                    out.notes.append(missing_texture(tex, name))
                    continue
                if not where:
                    moved = True
                    out.notes.append(f"texture {tex} found by name in the folder, not where {name} points "
                                     "(used from the folder)")
                out.textures[ref.name] = ref  # every texture by its file name, beside the rewritten .mtl
                cut = mline.rindex(tex)
                mline = mline[:cut] + ref.name + mline[cut + len(tex):]
            lines.append(mline)
        out.materials[name] = "\n".join(lines) + "\n"
    return out if moved else None


def model_resources(path: Path, warnings: list[str] | None = None) -> dict[str, Path]:
    """Files a model pulls in besides itself (buffers, textures, materials), by their reference name.

    Also the cheap pre-checks that must happen before hashing: GLB header sanity and missing files. A
    glTF buffer or image that is missing is an error; an OBJ's missing material or texture is appended
    to ``warnings`` when a list is given (ingest records it as a flag), an error otherwise.
    """
    suffix = path.suffix.lower()
    if suffix == ".glb":
        return _gltf_resources(path, _glb_json(path))
    if suffix == ".gltf":
        try:
            doc = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise IngestError(f"not a glTF JSON file: {exc}") from None
        if not isinstance(doc, dict) or "asset" not in doc:
            raise IngestError("not a glTF JSON file: no 'asset' object")
        return _gltf_resources(path, doc)
    if suffix == ".obj":
        return _obj_resources(path, warnings)
    return {}
