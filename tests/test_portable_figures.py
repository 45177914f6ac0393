"""The shape alignment's figures are the same bits on every machine (issue 69: a Ray cluster of mixed nodes).

numpy's ``@`` and ``np.linalg`` run OpenBLAS kernels chosen by the CPU, and ICP follows near-ties, so the
figures of one pair differed from one machine to another (the held-back copy pool: 382 of 1,153 between the
SkylakeX and Haswell kernels; docs/curation.md, "Figures that follow the machine"). Here the same surface
samples (written once by this process) are aligned in child processes that run other BLAS kernels
(``OPENBLAS_CORETYPE``) and other numpy SIMD paths (``NPY_DISABLE_CPU_FEATURES``), and every figure must be
equal to the last bit. x86-64 only (the kernels named are x86 ones)."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from copy_pool import pool

from mixcount.curation.finding import descriptors as D

CHILD = r"""
import json, sys
import numpy as np
from mixcount.curation.finding import shape_match as S
data = np.load(sys.argv[1])
shapes = [S.normalise(data[k]) for k in sorted(data.files)]
out = {"digests": [s.digest for s in shapes], "pairs": [], "primitives": []}
for i in range(len(shapes)):
    for j in range(i + 1, len(shapes)):
        m = S.match(shapes[i], shapes[j], max_squash=1.34)
        out["pairs"].append([m.distance, float(m.stretch), m.rotation.tolist()])
for s in shapes[:4]:
    out["primitives"].append(S.primitive_distance(s))
print(json.dumps(out))
"""

# other BLAS kernels every x86-64 CPU runs, and numpy without its AVX2 / AVX-512 loops
VARIANTS = {
    "nehalem kernels": {"OPENBLAS_CORETYPE": "Nehalem"},
    "prescott kernels": {"OPENBLAS_CORETYPE": "Prescott"},
    "numpy baseline SIMD": {"NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX2 FMA3"},
}


def _figures(samples: Path, env: dict[str, str]) -> dict:
    got = subprocess.run([sys.executable, "-c", CHILD, str(samples)], capture_output=True, text=True, timeout=600,
                         env={**os.environ, "OPENBLAS_NUM_THREADS": "1", **env})
    assert got.returncode == 0, got.stderr[-2000:]
    return json.loads(got.stdout)


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="the BLAS kernels named are x86-64 ones")
def test_alignment_figures_are_the_same_bits_under_other_blas_kernels_and_simd(tmp_path):
    rng = np.random.default_rng(5)
    entries = pool(seed=3)[:8]  # two originals and their copies (other resolution, a squash, a mix of changes)
    samples = {f"{k:02d}_{name}": D.sample_surface(v, f, 3000, rng).astype(np.float32).astype(np.float64)
               for k, (name, _, v, f) in enumerate(entries)}
    path = tmp_path / "samples.npz"
    np.savez(path, **samples)
    here = _figures(path, {})
    assert len(here["pairs"]) == 28 and len(set(here["digests"])) == 8
    assert min(p[0] for p in here["pairs"]) < 0.05 < max(p[0] for p in here["pairs"])  # copies and other shapes
    for name, env in VARIANTS.items():
        assert _figures(path, env) == here, name


def test_a_flat_object_aligns_and_fits_like_any_other():
    """A sheet's samples span a plane: the Gram matrix of ICP's least squares is singular there, and the
    portable solve gives the minimum-norm solution as ``np.linalg.lstsq`` does (not an error)."""
    from mixcount.curation.finding import portable_linalg as L
    from mixcount.curation.finding import shape_match as S

    rng = np.random.default_rng(2)
    a = np.c_[rng.normal(size=(200, 2)), np.zeros(200)]
    b = rng.normal(size=(200, 3))
    assert np.allclose(L.lstsq3(a, b), np.linalg.lstsq(a, b, rcond=None)[0], atol=1e-12)
    sheet = np.c_[rng.uniform(-1.0, 1.0, (3000, 2)) * [1.0, 0.7], np.zeros(3000)]
    slab = rng.uniform(-1.0, 1.0, (3000, 3)) * [1.0, 0.7, 0.3]
    flat = S.normalise(sheet)
    assert 0.0 < S.primitive_distance(flat) < 0.2
    again = S.normalise(sheet[::-1].copy())  # the same sheet, other sample order
    assert S.match(flat, again, max_squash=1.34).distance < 0.03 < S.match(flat, S.normalise(slab), max_squash=1.34).distance
