"""Compact depth / normal files: every format round-trips within its documented precision, marks "no
surface" the same way, loads from a file or a scene folder, and old float32 .npy passes still load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def _scene_like(h: int = 96, w: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """Planar depth of a tilted floor with a sphere on it (metres, 0 above the horizon) and its normals."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    depth = np.where(yy > h * 0.2, 12.0 + 30.0 * (h - yy) / h, 0.0)
    normals = np.zeros((h, w, 3))
    normals[yy > h * 0.2] = [0.0, 0.8, 0.6]
    ball = (xx - w / 2) ** 2 + (yy - h / 2) ** 2 < (h / 4) ** 2
    v = rng.normal(size=(int(ball.sum()), 3))
    v[:, 2] = np.abs(v[:, 2])
    normals[ball] = v / np.linalg.norm(v, axis=1, keepdims=True)
    depth[ball] = 11.0 + rng.random(int(ball.sum()))
    return depth.astype(np.float32), normals.astype(np.float32)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = a.astype(np.float64), b.astype(np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1)))


@pytest.mark.parametrize("fmt", ["png16", "exr32", "npy"])
def test_depth_round_trip(tmp_path: Path, fmt: str) -> None:
    from mixcount.annotate.passes import write_depth
    from mixcount.dataset import read_depth

    depth, _ = _scene_like()
    rec = write_depth(tmp_path, depth, fmt)
    back = read_depth(tmp_path / rec["file"])
    assert back.dtype == np.float32 and back.shape == depth.shape
    assert ((back == 0) == (depth == 0)).all()  # no surface stays no surface, and only there
    err = np.abs(back - depth).max()
    if fmt == "png16":
        assert rec["unit_m"] == 1e-3  # 42 m fits 65535 steps of 1 mm, not of 0.5 mm
        assert err <= rec["max_error_m"] + 1e-5 and err > 0  # + float32 rounding at 42 m
    else:
        assert err == 0.0
    assert np.array_equal(read_depth(tmp_path), back)  # a scene folder works too


def test_depth_unit_follows_the_farthest_surface(tmp_path: Path) -> None:
    from mixcount.annotate.passes import depth_unit, write_depth
    from mixcount.dataset import read_depth

    assert depth_unit(6.0) == 1e-4 and depth_unit(100.0) == 2e-3
    with pytest.raises(ValueError, match="exr32"):
        depth_unit(1000.0)
    near = np.full((4, 4), 0.00004, dtype=np.float32)  # closer than half a step: still a surface
    rec = write_depth(tmp_path, near, "png16")
    assert (read_depth(tmp_path / rec["file"]) > 0).all()


@pytest.mark.parametrize("fmt,max_deg", [("png8", 0.5), ("exr16", 0.05), ("npy", 1e-3)])
def test_normals_round_trip(tmp_path: Path, fmt: str, max_deg: float) -> None:
    from mixcount.annotate.passes import write_normals
    from mixcount.dataset import read_normals

    _, normals = _scene_like()
    rec = write_normals(tmp_path, normals, fmt)
    back = read_normals(tmp_path / rec["file"])
    surf = np.any(normals != 0, axis=-1)
    assert back.dtype == np.float32 and back.shape == normals.shape
    assert (back[~surf] == 0).all() and np.any(back[surf] != 0, axis=-1).all()
    assert _angle_deg(back[surf], normals[surf]).max() < max_deg


def test_old_npy_scene_folder_loads(tmp_path: Path) -> None:
    from mixcount.dataset import read_depth, read_normals

    depth, normals = _scene_like()
    np.save(tmp_path / "depth.npy", depth)  # a dataset written before the compact formats
    np.save(tmp_path / "normal.npy", normals)
    assert np.array_equal(read_depth(tmp_path), depth) and np.array_equal(read_normals(tmp_path), normals)
    with pytest.raises(FileNotFoundError):
        read_depth(tmp_path / "nothing")


def test_parse_passes() -> None:
    from mixcount.annotate.passes import parse_passes

    assert parse_passes("normal, depth") == ("depth", "normal")
    assert parse_passes(["instance", "class", "depth", "normal"]) == ("instance", "class", "depth", "normal")
    with pytest.raises(ValueError, match="rgb is always written"):
        parse_passes("depth,albedo")
