"""Union-find over integer ids: the groupings of the mapping's label merges and evidence decisions and of the
long scans' furniture stops."""

from __future__ import annotations


class DisjointSets:
    """Disjoint sets of integer ids, each id its own set until attached. ``find`` halves the paths it walks.

    The caller picks the root that a union keeps (``attach``): a label merge keeps one label's id, an evidence
    decision the group with more neighbours.

    Examples:
        >>> sets = DisjointSets()
        >>> sets.union(1, 2)
        2
        >>> sets.find(1), sets.find(3)
        (2, 3)
        >>> sets.groups()
        {2: [1, 2]}
    """

    def __init__(self) -> None:
        self.parent: dict[int, int] = {}

    def __bool__(self) -> bool:
        """Whether any set was attached to another."""
        return bool(self.parent)

    def find(self, v: int) -> int:
        """The root of ``v``'s set (``v`` itself where it was never attached)."""
        parent = self.parent
        while parent.get(v, v) != v:
            parent[v] = parent.get(parent[v], parent[v])
            v = parent[v]
        return v

    def attach(self, root: int, onto: int) -> None:
        """The set whose root is ``root`` joins the set whose root is ``onto``, which stays the root."""
        if root != onto:
            self.parent[root] = onto

    def union(self, a: int, b: int) -> int:
        """Joins the sets of ``a`` and ``b`` (``b``'s root stays the root); returns the root."""
        ra, rb = self.find(a), self.find(b)
        self.attach(ra, rb)
        return rb

    def groups(self) -> dict[int, list[int]]:
        """Each set that a union touched, by its root: its ids (attached ones and their roots), sorted."""
        ids = set(self.parent) | set(self.parent.values())
        out: dict[int, list[int]] = {}
        for v in sorted(ids):
            out.setdefault(self.find(v), []).append(v)
        return out
