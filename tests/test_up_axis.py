"""Telling the up axis (issue 35, item 4): Z-up geometry saved as GLB (common from exporters) is read Y-up
by glTF's rule, so a bowl lies on its side. The user sees a warning naming the container whose opening
does not face up and how to fix it; ``"up_axis": "Z"`` in its ``metadata.json`` or ``catalog ingest
--up-axis Z`` is honoured (stored as ``source_up_axis``, the bowl measured standing), a re-ingest with the
axis stated measures the object again, and a bad axis is an error before the catalog is touched.

User's side: the CLI (``catalog ingest``, ``catalog show --json``), real ingest (trimesh, pymeshlab, SQLite)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from mixcount.cli import main

RADIUS, HEIGHT = 0.08, 0.06


def z_up_bowl_glb(path: Path) -> None:
    """An open bowl (a cylinder without its top cap), opening towards +Z, written as it is into a GLB."""
    cyl = trimesh.creation.cylinder(radius=RADIUS, height=HEIGHT, sections=48)
    bowl = trimesh.Trimesh(cyl.vertices, cyl.faces[cyl.face_normals[:, 2] < 0.9])
    path.parent.mkdir(parents=True, exist_ok=True)
    bowl.export(path)


def cli(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(args))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def show(capsys, db: str, oid: int = 1) -> dict:
    code, out, err = cli(capsys, "--db", db, "catalog", "show", str(oid), "--json")
    assert code == 0, err
    return dict(json.loads(out))


def test_glb_read_y_up_warns_and_the_stated_axis_is_honoured(tmp_path, capsys):
    plain = tmp_path / "plain"
    z_up_bowl_glb(plain / "bowl.glb")
    db = str(tmp_path / "catalog.db")

    # nothing stated: glTF's rule, and a warning that says what is wrong and what to do
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(plain), "--workers", "1")
    assert code == 0, err
    assert "container #1 'bowl': its opening faces -Y, not up (+Z), read with up axis Y" in err
    assert "--up-axis Z" in err and '"up_axis": "Z"' in err
    rec = show(capsys, db)
    assert rec["source_up_axis"] == "Y" and rec["dims_m"][2] == pytest.approx(2 * RADIUS, abs=1e-3)

    # the flag: the same object measured again, standing, and no warning
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(plain), "--workers", "1", "--up-axis", "Z",
                         "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert (summary["updated"], summary["container_warnings"]) == (1, [])
    assert "opening faces" not in err
    rec = show(capsys, db)
    assert rec["source_up_axis"] == "Z" and rec["dims_m"][2] == pytest.approx(HEIGHT, abs=1e-3)


def test_up_axis_in_metadata_json_is_honoured(tmp_path, capsys):
    folder = tmp_path / "lib" / "serving_bowl"
    z_up_bowl_glb(folder / "model.glb")
    (folder / "metadata.json").write_text(json.dumps({"name": "Serving bowl", "up_axis": "Z"}))
    db = str(tmp_path / "catalog.db")
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(tmp_path / "lib"), "--workers", "1", "--json")
    assert code == 0, err
    summary = json.loads(out)
    rec = show(capsys, db)
    assert rec["name"] == "Serving bowl" and rec["source_up_axis"] == "Z"
    assert rec["dims_m"][2] == pytest.approx(HEIGHT, abs=1e-3)
    assert summary["container_warnings"] == [] and "opening faces" not in err


def test_bad_up_axis_is_an_error_before_the_catalog_is_made(tmp_path, capsys):
    z_up_bowl_glb(tmp_path / "plain" / "bowl.glb")
    db = tmp_path / "catalog.db"
    code, out, err = cli(capsys, "--db", str(db), "catalog", "ingest", str(tmp_path / "plain"), "--up-axis", "up")
    assert code != 0
    assert "unknown up axis 'up': give X, Y, Z or auto" in err
    assert not db.exists()


def mask_aspect(db: str, oid: int = 1) -> float:
    """Width / height of the object's pixels on its canonical render."""
    from mixcount.catalog.db import open_catalog
    from mixcount.curation.renders import canonical_render_path, mask_path_for

    cat = open_catalog(db, data_dir="")
    try:
        with cat.session() as s:
            path = canonical_render_path(s, oid)
    finally:
        cat.close()
    assert path is not None
    ys, xs = np.nonzero(np.asarray(Image.open(mask_path_for(path))) > 127)
    return float(np.ptp(xs) + 1) / float(np.ptp(ys) + 1)


@pytest.mark.blender
def test_canonical_render_shows_the_object_in_the_stated_frame(tmp_path, capsys):
    """The contact sheet / external exemplar shows the bowl as the scenes place it: on its side while it is
    read Y-up, standing (wide and low) once its up axis is stated (the render is redone by the re-ingest)."""
    z_up_bowl_glb(tmp_path / "plain" / "bowl.glb")
    db = str(tmp_path / "catalog.db")
    small = ["--db", db, "--config", "quick", "--set", "canonical_render.resolution=48", "--set", "canonical_render.samples=1",
             "--set", "canonical_render.elevation_deg=0.0", "--set", "canonical_render.azimuth_deg=0.0"]  # seen from the front (-Y)
    assert cli(capsys, *small, "catalog", "ingest", str(tmp_path / "plain"), "--workers", "1")[0] == 0
    assert cli(capsys, *small, "catalog", "render")[0] == 0
    lying = mask_aspect(db)
    assert cli(capsys, *small, "catalog", "ingest", str(tmp_path / "plain"), "--workers", "1", "--up-axis", "Z")[0] == 0
    code, out, err = cli(capsys, *small, "catalog", "render")
    assert code == 0 and "1 rendered" in out + err
    standing = mask_aspect(db)
    assert standing > 2.0 and lying < 1.2, (standing, lying)  # 0.16 x 0.06 m standing; the rim's circle lying
