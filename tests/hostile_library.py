"""A hostile library, built by the tests (issue 68 item 8): links out of it, references out of it in every
kind of file ingest reads, metadata of other meanings, description bombs and odd names, around small real
public models (assimp's BoxTextured glTF, pybullet's cube OBJ: tests/public_packages.py).

``build(tmp)`` lays out::

    tmp/secret/   secret.png (a real PNG carrying SECRET in a text chunk), secret.bin, secret.json,
                  evil.mtl (map_Kd secret.png), evil.obj
    tmp/outside/  a model folder outside the library
    tmp/lib/      the library: one folder per case (:data:`CASES` names each and what it tries)

Every file outside the library holds :data:`SECRET`: a scan of a catalog, its data folder and an output
for those bytes tells whether anything from outside got in.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import zlib
from pathlib import Path

from tests.public_packages import ASSIMP, ASSIMP_MODELS, PYBULLET, PYBULLET_DATA, deb_tree, wheel_tree

SECRET = b"MIXCOUNT-SECRET-7f3a9c"

# case folder -> what it tries (the tests assert each one's outcome)
CASES = {
    "rootlink": "a link to / (the issue's 3,447 objects)",
    "outlink": "a link to a folder outside holding a model",
    "chain_a": "a chain of links (inside -> inside -> outside)",
    "gltf_rel": "glTF image URI ../../../secret/secret.png",
    "gltf_abs": "glTF image URI /abs/secret.png",
    "gltf_file": "glTF image URI file:///abs/secret.png",
    "gltf_pct": "glTF image URI ..%2F..%2F..%2Fsecret%2Fsecret.png (percent-encoded ../)",
    "glb_rel": "a GLB (binary chunk inside) whose image URI is ../../../secret/secret.png",
    "gltf_buf_abs": "glTF buffer with an absolute URI",
    "gltf_buf_file": "glTF buffer with a file:// URI",
    "mtl_abs": "MTL map_Kd /abs/secret.png",
    "gso_bump": "a Google Scanned Objects folder whose model.mtl adds bump /abs/secret.png to its own texture",
    "mtllib_out": "OBJ mtllib ../../secret/evil.mtl",
    "tex_link": "a texture that is a link to the secret (and one to /etc/passwd)",
    "model_link": "a model file that is a link to a model outside",
    "meta_link": "metadata.json that is a link to a JSON file outside",
    "licence_link": "a LICENSE that is a link to a file outside (its text would be the objects' licence)",
    "urdf_out": "a URDF whose mesh filename leaves the library",
    "urdf_bomb": "an entity-bomb URDF beside a model",
    "urdf_xxe": "a URDF with an external entity naming the secret",
    "meta_counts": "metadata.json with parts: 3, units: unknown, a list for a name",
    "odd name [x] 'q' ü": "a folder name with brackets, quotes, non-ASCII",
    "..dotted": "a folder named ..something (hidden: not walked)",
    "good_gltf": "the same glTF untouched (textured)",
    "step_bad": "an empty STEP file and one of garbage bytes (OpenCASCADE's own output must not reach the terminal)",
}


def _png_with_secret(path: Path) -> None:
    """A 4x4 red PNG with SECRET in a tEXt chunk, so that a copy of its bytes is found by a scan."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    raw = b"".join(b"\x00" + b"\xff\x00\x00" * 4 for _ in range(4))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 2, 0, 0, 0))
                     + chunk(b"tEXt", b"Comment\x00" + SECRET) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))


def sources() -> tuple[Path | None, Path | None, str]:
    """(assimp's BoxTextured glTF folder, pybullet_data, why not) from the public packages."""
    assimp, why = deb_tree(ASSIMP)
    if assimp is None:
        return None, None, why
    pyb, why = wheel_tree(PYBULLET)
    if pyb is None:
        return None, None, why
    return assimp / ASSIMP_MODELS / "glTF2" / "BoxTextured-glTF", pyb / PYBULLET_DATA, ""


def _gltf(src: Path, dest: Path, image: str | None = None, buffer: str | None = None) -> Path:
    dest.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        shutil.copy(f, dest / f.name)
    doc = json.loads((dest / "BoxTextured.gltf").read_text())
    if image is not None:
        doc["images"][0]["uri"] = image
    if buffer is not None:
        doc["buffers"][0]["uri"] = buffer
    (dest / "BoxTextured.gltf").write_text(json.dumps(doc))
    return dest / "BoxTextured.gltf"


def _glb(src: Path, dest: Path, image: str) -> Path:
    """assimp's BoxTextured as one GLB (its buffer in the binary chunk) whose image is an external URI."""
    dest.mkdir(parents=True, exist_ok=True)
    doc = json.loads((src / "BoxTextured.gltf").read_text())
    binary = (src / "BoxTextured0.bin").read_bytes()
    del doc["buffers"][0]["uri"]
    doc["images"][0]["uri"] = image
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = (struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942)
            + binary)
    (dest / "box.glb").write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
    return dest / "box.glb"


def _cube(pyb: Path, dest: Path, mtl: str | None = None, mtllib: str = "cube.mtl") -> Path:
    dest.mkdir(parents=True, exist_ok=True)
    text = (pyb / "cube.obj").read_text()
    lines = [ln for ln in text.splitlines() if not ln.startswith(("mtllib", "usemtl"))]
    first_f = next(i for i, ln in enumerate(lines) if ln.startswith("f "))
    lines[first_f:first_f] = ["usemtl m"]
    head = f"mtllib {mtllib}\n" if mtl is not None or mtllib != "cube.mtl" else ""
    (dest / "cube.obj").write_text(head + "\n".join(lines) + "\n")
    if mtl is not None:
        (dest / "cube.mtl").write_text(f"newmtl m\nKd 0.8 0.8 0.8\nmap_Kd {mtl}\n")
    return dest / "cube.obj"


BOMB = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lollollollollollollollollollol">
""" + "".join(f'<!ENTITY lol{i} "{("&lol" + (str(i - 1) if i > 1 else "") + ";") * 10}">\n' for i in range(1, 10)) + """]>
<robot name="&lol9;"><link name="b"><visual><geometry><mesh filename="cube.obj" scale="0.001 0.001 0.001"/>
</geometry></visual></link></robot>
"""


def build(tmp: Path) -> tuple[Path | None, str]:
    """The hostile library under ``tmp`` (see the module docstring): (tmp / "lib", "") or (None, why)."""
    box, pyb, why = sources()
    if box is None or pyb is None:
        return None, why
    secret, outside, lib = tmp / "secret", tmp / "outside", tmp / "lib"
    secret.mkdir(parents=True)
    _png_with_secret(secret / "secret.png")
    (secret / "secret.bin").write_bytes(SECRET + (box / "BoxTextured0.bin").read_bytes()[len(SECRET):])
    (secret / "secret.json").write_text(json.dumps({"name": SECRET.decode(), "category": SECRET.decode()}))
    (secret / "evil.mtl").write_text(f"# {SECRET.decode()}\nnewmtl m\nmap_Kd secret.png\n")
    _cube(pyb, outside / "evil_model")
    with open(outside / "evil_model" / "cube.obj", "a") as fh:
        fh.write(f"# {SECRET.decode()}\n")
    lib.mkdir()

    os.symlink("/", lib / "rootlink")
    os.symlink(outside, lib / "outlink")
    os.symlink(lib / "chain_b", lib / "chain_a")  # inside -> inside -> outside
    os.symlink(outside, lib / "chain_b")
    sec = secret / "secret.png"
    _gltf(box, lib / "gltf_rel" / "box", image="../../../secret/secret.png")
    _gltf(box, lib / "gltf_abs" / "box", image=str(sec))
    _gltf(box, lib / "gltf_file" / "box", image=sec.as_uri())
    _gltf(box, lib / "gltf_pct" / "box", image="..%2F..%2F..%2Fsecret%2Fsecret.png")
    _glb(box, lib / "glb_rel" / "box", image="../../../secret/secret.png")
    _gltf(box, lib / "gltf_buf_abs" / "box", buffer=str(secret / "secret.bin"))
    _gltf(box, lib / "gltf_buf_file" / "box", buffer=(secret / "secret.bin").as_uri())
    _gltf(box, lib / "good_gltf" / "box")
    _cube(pyb, lib / "mtl_abs" / "cube", mtl=str(sec))
    _cube(pyb, lib / "mtllib_out" / "cube", mtllib="../../../secret/evil.mtl")
    gso = lib / "gso_bump" / "Cube_Scan"
    _cube(pyb, gso / "meshes", mtllib="model.mtl")
    (gso / "meshes" / "cube.obj").rename(gso / "meshes" / "model.obj")
    (gso / "meshes" / "model.mtl").write_text(f"newmtl m\nmap_Kd texture.png\nbump {sec}\n")
    (gso / "materials" / "textures").mkdir(parents=True)
    shutil.copy(pyb / "cube.png", gso / "materials" / "textures" / "texture.png")
    (gso / "model.config").write_text("<model><name>Cube_Scan</name></model>\n")
    _cube(pyb, lib / "tex_link" / "cube", mtl="tex.png")
    os.symlink(sec, lib / "tex_link" / "cube" / "tex.png")
    _cube(pyb, lib / "tex_link" / "passwd", mtl="pw.png")
    os.symlink("/etc/passwd", lib / "tex_link" / "passwd" / "pw.png")
    (lib / "model_link").mkdir()
    os.symlink(outside / "evil_model" / "cube.obj", lib / "model_link" / "linked.obj")
    _cube(pyb, lib / "licence_link" / "cube")
    os.symlink(secret / "secret.json", lib / "licence_link" / "LICENSE")
    _cube(pyb, lib / "meta_link" / "cube")
    os.symlink(secret / "secret.json", lib / "meta_link" / "cube" / "metadata.json")
    folder = _cube(pyb, lib / "urdf_out" / "cube").parent
    (folder / "cube.urdf").write_text('<robot name="cube"><link name="b"><visual><geometry>'
                                      '<mesh filename="../../../outside/evil_model/cube.obj" scale="0.01 0.01 0.01"/>'
                                      "</geometry></visual></link></robot>")
    folder = _cube(pyb, lib / "urdf_bomb" / "cube").parent
    (folder / "cube.urdf").write_text(BOMB)
    folder = _cube(pyb, lib / "urdf_xxe" / "cube").parent
    (folder / "cube.urdf").write_text(f'<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY x SYSTEM "{(secret / "secret.json").as_uri()}">]>\n'
                                      '<robot name="&x;"><link name="b"><visual><geometry><mesh filename="cube.obj" '
                                      'scale="0.001 0.001 0.001"/></geometry></visual></link></robot>')
    for i, record in enumerate(({"parts": 3, "name": "Counted cube"}, {"units": "unknown", "name": ["a", "b"]},
                                {"name": [], "category": {"x": 1}, "up_axis": 7})):
        folder = _cube(pyb, lib / "meta_counts" / f"cube{i}").parent
        (folder / "metadata.json").write_text(json.dumps(record))
    for name, data in (("empty", b""), ("garbage", bytes(range(256)) * 8)):
        (lib / "step_bad" / name).mkdir(parents=True)
        (lib / "step_bad" / name / f"{name}.step").write_bytes(data)
    _cube(pyb, lib / "odd name [x] 'q' ü" / "cube")
    _cube(pyb, lib / "..dotted" / "cube")
    return lib, ""
