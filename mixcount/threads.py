"""One BLAS thread for work made of many small matrices.

The curation filter aligns shapes with thousands of tiny products, least-squares fits and SVDs (1500 x 3
points, 3 x 3 maps). OpenBLAS splits each across its threads; on matrices this small the threads spend
their time waking and waiting, and on a machine whose cores are already busy (two test processes, or a
compose running beside the filter) they make it several times slower: 1.53 s -> 0.24 s for two matches
on the shared 2-core machine, with the same distances to the last digit (docs/curation.md).
:func:`one_blas_thread` limits BLAS to one thread for a block and restores it after, so it changes
nothing outside that block (Cycles, trimesh and pymeshlab keep their own threads).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS (OpenBLAS, MKL) limited to one thread inside the block."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
