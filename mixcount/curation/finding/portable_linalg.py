"""Small linear algebra whose result bits do not depend on the machine: no BLAS, no LAPACK.

numpy's ``@`` and ``np.linalg`` call OpenBLAS, which picks its kernels by the CPU it runs on (SkylakeX,
Haswell, Sandybridge, ...). Their results differ in the last bits from one kernel to another, and the shape
alignment (:mod:`mixcount.curation.finding.shape_match`) turns last bits into other figures: ICP and the ranking
of its starts follow near-ties, so another local optimum is found. On the held-back copy pool (the same
items), 413 of 1,153 pair figures differed between ``OPENBLAS_CORETYPE=SkylakeX`` and ``Haswell`` (338 by more
than 0.001), and two flags with them (docs/curation.md, "Figures that follow the machine"). A catalog filtered on a Ray cluster of
mixed machines got figures that depended on the node each task ran on.

Everything here is made of numpy's element-wise operations, its pairwise-summed reductions, ``einsum`` without
``optimize`` (numpy's own loops, not BLAS) and square roots (correctly rounded everywhere): the same bits on
every x86-64 machine with the same numpy. No transcendental functions (glibc picks FMA variants of those by
CPU, and numpy has AVX-512 versions of its own); ``math.sqrt`` and ``np.sqrt`` are correctly rounded. The eigenvectors come from cyclic Jacobi rotations, exact to a few ulps for the 3x3 matrices used here.
"""

from __future__ import annotations

import math

import numpy as np

JACOBI_SWEEPS = 12  # a 3x3 symmetric matrix is diagonal to machine precision after 4-6 (quadratic convergence)


def turn(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``points @ m.T`` (each row mapped by ``m``)."""
    return np.einsum("pj,ij->pi", points, m)


def turn_each(points: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """``points @ m.T`` for every ``m`` of ``ms`` (k, 3, 3): shape (k, points, 3)."""
    return np.einsum("pj,rij->rpi", points, ms)


def mat(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` of two small matrices."""
    return np.einsum("ij,jk->ik", a, b)


def gram(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a.T @ b`` of two (n, 3) arrays."""
    return np.einsum("pi,pj->ij", a, b)


def det3(m: np.ndarray) -> float:
    """Determinant of a 3x3 matrix."""
    return float(m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                 - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                 + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))


def inv3(m: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix (adjugate over determinant); raises on a singular one."""
    d = det3(m)
    if d == 0.0:
        raise np.linalg.LinAlgError("singular 3x3 matrix")
    adj = np.array([
        [m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1], m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2], m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]],
        [m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2], m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0], m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]],
        [m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0], m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1], m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]],
    ])
    return adj / d


RANK_TOLERANCE = 1e-12  # det(a.T a) under this x (its mean eigenvalue) ** 3: rank deficient (flat samples)


def lstsq3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least-squares ``x`` of ``a @ x ~ b`` for (n, 3) arrays: the normal equations where ``a`` has full
    rank; the minimum-norm solution (as ``np.linalg.lstsq`` gives) where it has not: the samples of a flat
    object (a sheet, a decal) span a plane, and their Gram matrix is singular."""
    g = gram(a, a)
    mean = float(g[0, 0] + g[1, 1] + g[2, 2]) / 3.0
    if det3(g) > RANK_TOLERANCE * mean ** 3:
        return mat(inv3(g), gram(a, b))
    w, v = sym_eig3(g)  # pseudo-inverse: only the directions the points span
    keep = w > max(float(w[-1]), 0.0) * (np.finfo(np.float64).eps * max(a.shape)) ** 2
    inv_w = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    return mat(mat(v * inv_w[None, :], v.T), gram(a, b))


def sym_eig3_many(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors (columns) of each symmetric 3x3 matrix of ``a`` (..., 3, 3),
    as ``np.linalg.eigh`` gives them up to each vector's sign."""
    a = np.array(a, dtype=np.float64, copy=True)
    shape = a.shape[:-2]
    a = a.reshape(-1, 3, 3)
    v = np.broadcast_to(np.eye(3), a.shape).copy()
    scale = np.abs(a).sum(axis=(1, 2))
    for _ in range(JACOBI_SWEEPS):
        if (np.abs(a[:, 0, 1]) + np.abs(a[:, 0, 2]) + np.abs(a[:, 1, 2]) <= 1e-18 * scale).all():
            break  # every matrix diagonal to well within an ulp of its entries
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = a[:, p, q]
            live = apq != 0.0
            safe = np.where(live, apq, 1.0)
            with np.errstate(over="ignore", divide="ignore"):  # a negligible a_pq: tau is inf, t is 0
                tau = (a[:, q, q] - a[:, p, p]) / (2.0 * safe)
                t = np.where(tau >= 0.0, 1.0, -1.0) / (np.abs(tau) + np.sqrt(1.0 + tau * tau))
            t = np.where(live, t, 0.0)
            c = 1.0 / np.sqrt(1.0 + t * t)
            s = t * c
            # A <- J^T A J with J the rotation in the (p, q) plane
            ap, aq = a[:, :, p].copy(), a[:, :, q].copy()
            a[:, :, p] = c[:, None] * ap - s[:, None] * aq
            a[:, :, q] = s[:, None] * ap + c[:, None] * aq
            ap, aq = a[:, p, :].copy(), a[:, q, :].copy()
            a[:, p, :] = c[:, None] * ap - s[:, None] * aq
            a[:, q, :] = s[:, None] * ap + c[:, None] * aq
            vp, vq = v[:, :, p].copy(), v[:, :, q].copy()
            v[:, :, p] = c[:, None] * vp - s[:, None] * vq
            v[:, :, q] = s[:, None] * vp + c[:, None] * vq
    w = np.stack([a[:, 0, 0], a[:, 1, 1], a[:, 2, 2]], axis=1)
    order = np.argsort(w, axis=1, kind="stable")
    w = np.take_along_axis(w, order, axis=1)
    v = np.take_along_axis(v, order[:, None, :], axis=2)
    return w.reshape(*shape, 3), v.reshape(*shape, 3, 3)


def sym_eig3(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sym_eig3_many` of one matrix, in Python floats (IEEE doubles; ~20 times faster than numpy
    calls for one 3x3), stopping once every off-diagonal entry is zero or negligible."""
    m = [[float(x) for x in row] for row in np.asarray(a, dtype=np.float64)]
    v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    scale = abs(m[0][0]) + abs(m[1][1]) + abs(m[2][2]) + abs(m[0][1]) + abs(m[0][2]) + abs(m[1][2])
    for _ in range(4 * JACOBI_SWEEPS):
        if abs(m[0][1]) + abs(m[0][2]) + abs(m[1][2]) <= 1e-18 * scale:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = m[p][q]
            if apq == 0.0:
                continue
            tau = (m[q][q] - m[p][p]) / (2.0 * apq)
            if abs(tau) > 1e150:
                continue  # negligible against the diagonal
            t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + math.sqrt(1.0 + tau * tau))
            c = 1.0 / math.sqrt(1.0 + t * t)
            s = t * c
            for r in range(3):  # columns p, q
                mp, mq = m[r][p], m[r][q]
                m[r][p], m[r][q] = c * mp - s * mq, s * mp + c * mq
            for r in range(3):  # rows p, q
                mp, mq = m[p][r], m[q][r]
                m[p][r], m[q][r] = c * mp - s * mq, s * mp + c * mq
            for r in range(3):
                vp, vq = v[r][p], v[r][q]
                v[r][p], v[r][q] = c * vp - s * vq, s * vp + c * vq
    w = [m[0][0], m[1][1], m[2][2]]
    order = sorted(range(3), key=lambda k: w[k])
    return np.array([w[k] for k in order]), np.array([[v[r][k] for k in order] for r in range(3)])


def svd3(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``u, s, vt`` of a 3x3 matrix as ``np.linalg.svd`` gives them (``s`` descending, ``u @ diag(s) @ vt == m``),
    up to the signs of paired singular vectors; from the eigenvectors of ``m.T @ m``."""
    w, v = sym_eig3(mat(m.T, m))
    v = v[:, ::-1]  # descending
    s = np.sqrt(np.maximum(w[::-1], 0.0))
    mv = mat(m, v)
    u0 = mv[:, 0] / s[0] if s[0] > 0 else np.array([1.0, 0.0, 0.0])
    u1 = mv[:, 1] - float((mv[:, 1] * u0).sum()) * u0
    n1 = float(np.sqrt((u1 * u1).sum()))
    if n1 > 0:
        u1 = u1 / n1
    else:  # rank one: any unit vector orthogonal to u0
        pick = np.eye(3)[int(np.argmin(np.abs(u0)))]
        u1 = pick - float((pick * u0).sum()) * u0
        u1 = u1 / float(np.sqrt((u1 * u1).sum()))
    u2 = np.array([u0[1] * u1[2] - u0[2] * u1[1], u0[2] * u1[0] - u0[0] * u1[2], u0[0] * u1[1] - u0[1] * u1[0]])
    if float((mv[:, 2] * u2).sum()) < 0:  # the third singular value is >= 0: its vector points along m v2
        u2 = -u2
    return np.stack([u0, u1, u2], axis=1), s, v.T


def power(x: np.ndarray, k: int) -> np.ndarray:
    """``x ** k`` for a whole ``k >= 1`` by repeated multiplication (numpy sends other powers to ``pow``)."""
    out = np.array(x, dtype=np.float64, copy=True)
    for _ in range(k - 1):
        out = out * x
    return out


def root(x: np.ndarray, n: int) -> np.ndarray:
    """The real ``n``-th root of each ``x >= 0`` by Newton's iteration (``x ** (1 / n)`` without ``pow``, whose
    last bits follow the C library's CPU-specific variant): exact to an ulp or two, the same on every machine."""
    x = np.asarray(x, dtype=np.float64)
    y = np.where(x > 1.0, x, 1.0)  # from above: Newton for a convex function then falls monotonically
    for _ in range(200):
        nxt = ((n - 1) * y + x / power(y, n - 1)) / n
        if np.all(nxt >= y):
            break
        y = np.minimum(nxt, y)
    return np.where(x > 0, y, 0.0)


# cos and sin of the multiples of 15 degrees, from square roots only
_C15 = float(np.sqrt((1.0 + np.sqrt(3.0) / 2.0) / 2.0))
_S15 = float(np.sqrt((1.0 - np.sqrt(3.0) / 2.0) / 2.0))
_R2 = float(np.sqrt(0.5))
_H3 = float(np.sqrt(3.0) / 2.0)
_FIRST_QUADRANT = {0: (1.0, 0.0), 15: (_C15, _S15), 30: (_H3, 0.5), 45: (_R2, _R2), 60: (0.5, _H3), 75: (_S15, _C15)}


def cos_sin_deg(deg: float) -> tuple[float, float]:
    """cos and sin of a whole multiple of 15 degrees, from square roots (the same bits everywhere)."""
    k = int(round(deg))
    if k != deg or k % 15:
        raise ValueError(f"{deg} is not a multiple of 15 degrees")
    k %= 360
    quadrant, rest = divmod(k, 90)
    c, s = _FIRST_QUADRANT[rest]
    for _ in range(quadrant):  # a quarter turn: (c, s) -> (-s, c)
        c, s = -s, c
    return c, s
