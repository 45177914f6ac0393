"""Connected components of pairwise links (duplicate flags, caption collisions).

One union-find serves curation (duplicate groups), captioning (collision groups) and splits (groups that
must not span two splits), so all three agree on what a group is.
"""

from __future__ import annotations

from typing import Iterable


def connected_groups(pairs: Iterable[tuple[int, int]], members: Iterable[int] = ()) -> list[list[int]]:
    """Groups of ids linked by ``pairs``; ``members`` adds ids that may stand alone.

    Each group is sorted and the groups are sorted by their first id, so results are deterministic.
    """
    parent: dict[int, int] = {m: m for m in members}

    def find(x: int) -> int:
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b in pairs:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for x in sorted(parent):
        groups.setdefault(find(x), []).append(x)
    return sorted(groups.values(), key=lambda g: g[0])
