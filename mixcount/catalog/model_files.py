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
from typing import Any, TypeGuard
from urllib.parse import unquote

from mixcount.catalog.naming import safe_text
from mixcount.errors import IngestError
from mixcount.library_root import LibraryRoots, OutsideLibraryError

GLB_MAGIC = b"glTF"




def _is_external_uri(uri: str) -> bool:
    """A glTF URI read from a file: not embedded data (``file://`` is a file too: the roots judge it)."""
    return bool(uri) and not uri.startswith("data:") and ("://" not in uri or uri.lower().startswith("file:"))


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


def _gltf_resources(path: Path, doc: dict[str, Any], roots: LibraryRoots | None = None) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for kind, key in (("buffer", "buffers"), ("texture", "images")):
        for item in doc.get(key, []) or []:
            uri = item.get("uri", "") if isinstance(item, dict) else ""
            if not isinstance(uri, str) or not _is_external_uri(uri) or (roots is None and "://" in uri):
                continue
            if roots is not None:
                try:
                    ref = roots.resolve(uri, path.parent, f"glTF {kind}")
                except OutsideLibraryError as exc:
                    raise IngestError(f"{kind} {safe_text(uri)} refused: {exc.reason}") from None
            else:
                ref = (path.parent / unquote(uri)).resolve()
            if not ref.is_file():
                raise IngestError(f"missing {kind} file: {uri}")
            out[unquote(uri)] = ref
    return out


def _is_local_uri(uri: Any) -> TypeGuard[str]:
    """A glTF ``uri`` naming a file (relative, absolute or ``file://``), not embedded data."""
    return isinstance(uri, str) and bool(uri) and not uri.startswith("data:")


# a 1x1 grey PNG: the image an escaped glTF image reference is replaced with (no material uses it any more)
_BLANK_PNG = ("data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAAAAAA6fptVAAAACklEQVR4nGNoAAAAggCB"
              "d81ytgAAAABJRU5ErkJggg==")


def _drop_texture_uses(node: Any, textures: set[int]) -> None:
    """Remove every texture reference (``{"index": i}`` under a ``...Texture`` key) to ``textures``."""
    if isinstance(node, dict):
        for key in list(node):
            value = node[key]
            if (isinstance(value, dict) and key.lower().endswith("texture") and value.get("index") in textures):
                del node[key]
            else:
                _drop_texture_uses(value, textures)
    elif isinstance(node, list):
        for value in node:
            _drop_texture_uses(value, textures)


def _glb_parts(path: Path) -> tuple[dict[str, Any], bytes]:
    """(JSON document, the bytes after the JSON chunk) of a GLB."""
    data = path.read_bytes()
    chunk_len = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + chunk_len]), data[20 + chunk_len:]


def _glb_bytes(doc: dict[str, Any], rest: bytes) -> bytes:
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return GLB_MAGIC + struct.pack("<II", 2, 12 + len(body)) + body


def seal_gltf(path: Path, roots: LibraryRoots) -> Relinked | None:
    """A glTF/GLB whose image references leave the library (``../../../secret.png``, ``/abs.png``,
    ``file://``): rewritten so that it names none (the materials' uses of those images dropped: the object
    is untextured there, flagged with the reference and the reason), its other external files renamed
    ``res_<n>_<name>`` beside it; None when nothing leaves. A buffer that leaves is no part of the sealing:
    the object is broken (:func:`model_resources`). Staged by :func:`mixcount.catalog.layouts.discovery.stage`."""
    try:
        if path.suffix.lower() == ".glb":
            doc, rest = _glb_parts(path)
        else:
            doc, rest = json.loads(path.read_text()), b""
    except (OSError, ValueError, UnicodeDecodeError, struct.error):
        return None  # the pre-check reports the file
    if not isinstance(doc, dict):
        return None
    refused: dict[int, str] = {}
    for i, image in enumerate(doc.get("images") or []):
        uri = image.get("uri") if isinstance(image, dict) else None
        if _is_local_uri(uri):
            try:
                roots.resolve(uri, path.parent, "glTF image")
            except OutsideLibraryError as exc:
                refused[i] = f"texture {safe_text(uri)} refused: {exc.reason}; the object is untextured there"
    if not refused:
        return None
    out = Relinked({}, {}, list(refused.values()))
    for i in refused:
        doc["images"][i]["uri"] = _BLANK_PNG
    _drop_texture_uses(doc.get("materials"), {t for t, tex in enumerate(doc.get("textures") or [])
                                              if isinstance(tex, dict) and tex.get("source") in refused})
    for key in ("buffers", "images"):
        for n, item in enumerate(doc.get(key) or []):
            uri = item.get("uri") if isinstance(item, dict) else None
            if not _is_local_uri(uri):
                continue
            try:
                real = roots.resolve(uri, path.parent, "glTF file")
            except OutsideLibraryError:
                continue  # a buffer: model_resources breaks the object
            name = f"res_{key[0]}{n}_{real.name}"
            item["uri"] = name
            out.textures[name] = real
    if path.suffix.lower() == ".glb":
        out.model = _glb_bytes(doc, rest)
    else:
        out.model = json.dumps(doc, indent=1)
    return out


_MTL_MAP = re.compile(r"^\s*(map_\w+|bump|disp|decal|norm)\s+(.+?)\s*$", re.IGNORECASE)


def _texture_file(tex: str, mtl: Path, model: Path, roots: LibraryRoots | None = None,
                  also: tuple[Path, ...] = ()) -> tuple[Path | None, bool, str | None]:
    """(file, found where the reference points, why refused) of an MTL texture reference: first where it
    points (relative to the MTL, ``../cube.png`` included), then by its file name in the model's folder (a
    Windows path such as ``E:\\data\\table.png`` too). With ``roots``, a reference whose file lies outside
    the library is refused (None, False, the reason), not looked up by name."""
    ref = mtl.parent / tex
    if ref.is_file():
        if roots is not None:
            try:
                roots.resolve(tex, mtl.parent, "texture")
            except OutsideLibraryError as exc:
                return None, False, exc.reason
        return ref, True, None
    name = re.split(r"[\\/]", tex)[-1]
    for folder in dict.fromkeys((model.parent, mtl.parent, *also)):
        here = folder / name
        if name and here.is_file() and (roots is None or roots.contains(here)):
            return here, False, None
    return None, False, None


def refused_texture(tex: str, mtl_name: str, reason: str) -> str:
    """The warning of a texture reference refused (it leads outside the library)."""
    return f"texture {safe_text(tex)} in {mtl_name} refused: {reason}; a default material is used"


def missing_texture(tex: str, mtl_name: str) -> str:
    """The warning of a texture found neither where its material points nor by name."""
    return (f"missing texture file: {tex} (not where {mtl_name} points, nor by name in the folder; "
            "a default material is used)")


def _mtl_file(name: str, path: Path, roots: LibraryRoots | None) -> tuple[Path, str | None]:
    """(file, why refused) of an OBJ's ``mtllib`` name."""
    if roots is not None:
        try:
            roots.resolve(name, path.parent, "material file")
        except OutsideLibraryError as exc:
            return path.parent / name, exc.reason
    return path.parent / name, None


def _obj_resources(path: Path, warnings: list[str] | None, roots: LibraryRoots | None = None) -> dict[str, Path]:
    """An OBJ's material files and textures. A missing one is no error: the model loads with a default
    material, as any viewer opens it; each miss is appended to ``warnings`` (or raises without a list).
    With ``roots``, a material or texture outside the library is not read (a warning, or raises)."""
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
        mtl, outside = _mtl_file(name, path, roots)
        if outside:
            miss(f"material file {safe_text(name)} refused: {outside}; a default material is used")
            continue
        if not mtl.is_file():
            miss(f"missing material file: {name} (a default material is used)")
            continue
        out[name] = mtl
        for mline in mtl.read_text(errors="replace").splitlines():
            match = _MTL_MAP.match(mline)
            if not match:
                continue
            tex = match.group(2).split()[-1]  # options such as "-bm 1" come first; the file is last
            ref, where, why = _texture_file(tex, mtl, path, roots)
            if why:
                miss(refused_texture(tex, name, why))
                continue
            if ref is None:
                miss(missing_texture(tex, name))
                continue
            if not where:
                miss(f"texture {tex} found by name in the folder, not where {name} points")
            out[tex] = ref
    return out


@dataclass
class Relinked:
    """A model rewritten for its staged copy: the rewritten material files (by name), the files they and
    the model now name (by staged name), what was done (warnings), and the model's own rewritten content
    when its own references changed (an OBJ's ``mtllib`` or a glTF's URIs that left the library)."""

    materials: dict[str, str]
    textures: dict[str, Path]
    notes: list[str]
    model: str | bytes | None = None


def relink_textures(path: Path, roots: LibraryRoots | None = None, also: tuple[Path, ...] = ()) -> Relinked | None:
    """For an OBJ whose textures are found only by name (``../cube.png``, ``E:\\data\\table.png``), not at
    all, or (with ``roots``) outside the library: its materials rewritten to name them by file name (a
    missing or refused one left out, so that the model has its material's plain colour: Blender paints a
    missing image magenta), so that every loader (trimesh, Blender's importer) finds them when the model is
    staged beside them; an ``mtllib`` outside the library is dropped from the staged model itself.
    ``also``: more folders a texture is looked up in by name (GSO's ``materials/textures/``). None when
    nothing needs it."""
    if path.suffix.lower() != ".obj":
        return None
    try:
        raw = path.read_bytes()
    except OSError:
        return None
    text = raw.decode(errors="replace")
    out = Relinked({}, {}, [])
    moved = False
    dropped: list[str] = []
    for line in text.splitlines():
        if not line.startswith("mtllib"):
            continue
        name = line[len("mtllib"):].strip()
        if not name:
            continue
        mtl, outside = _mtl_file(name, path, roots)
        if outside:
            dropped.append(name)
            out.notes.append(f"material file {safe_text(name)} refused: {outside}; a default material is used")
            continue
        if not mtl.is_file():
            continue
        lines = []
        for mline in mtl.read_text(errors="replace").splitlines():
            match = _MTL_MAP.match(mline)
            if match:
                tex = match.group(2).split()[-1]
                ref, where, why = _texture_file(tex, mtl, path, roots, also)
                if ref is None:  # dropped: Blender would paint a missing image magenta, not a default material
                    moved = True
                    out.notes.append(refused_texture(tex, name, why) if why else missing_texture(tex, name))
                    continue
                if not where:
                    moved = True
                    out.notes.append(f"texture {tex} found by name in the folder, not where {name} points "
                                     "(used from the folder)")
                out.textures[ref.name] = ref  # every texture by its file name, beside the rewritten .mtl
                cut = mline.rindex(tex)
                mline = mline[:cut] + ref.name + mline[cut + len(tex):]
            lines.append(mline)
        out.materials[Path(name.replace("\\", "/")).name] = "\n".join(lines) + "\n"
    if dropped or (moved and any("/" in n.replace("\\", "/") for n in _mtllibs(text))):
        # the staged model names its materials by file name, beside it (one in another folder too)
        moved = True
        keep: list[bytes] = []
        for row in raw.split(b"\n"):
            if row.startswith(b"mtllib"):
                named = row[len(b"mtllib"):].decode(errors="replace").strip()
                if named in dropped:
                    continue
                row = b"mtllib " + Path(named.replace("\\", "/")).name.encode()
            keep.append(row)
        out.model = b"\n".join(keep)
    return out if moved else None


def _mtllibs(text: str) -> list[str]:
    return [ln[len("mtllib"):].strip() for ln in text.splitlines() if ln.startswith("mtllib") and ln[6:].strip()]


def model_resources(path: Path, warnings: list[str] | None = None, roots: LibraryRoots | None = None
                    ) -> dict[str, Path]:
    """Files a model pulls in besides itself (buffers, textures, materials), by their reference name.

    Also the cheap pre-checks that must happen before hashing: GLB header sanity and missing files. A
    glTF buffer or image that is missing is an error; an OBJ's missing material or texture is appended
    to ``warnings`` when a list is given (ingest records it as a flag), an error otherwise. With ``roots``
    (:class:`mixcount.library_root.LibraryRoots`) no reference outside them is read: a glTF buffer or image
    that leaves is an error (ingest's staged copy has dropped the images already: :func:`seal_gltf`), an
    OBJ's material or texture a warning.
    """
    suffix = path.suffix.lower()
    if suffix == ".glb":
        return _gltf_resources(path, _glb_json(path), roots)
    if suffix == ".gltf":
        try:
            doc = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise IngestError(f"not a glTF JSON file: {exc}") from None
        if not isinstance(doc, dict) or "asset" not in doc:
            raise IngestError("not a glTF JSON file: no 'asset' object")
        return _gltf_resources(path, doc, roots)
    if suffix == ".obj":
        return _obj_resources(path, warnings, roots)
    return {}
