"""``ogscene3d._disjoint_sets``: the union-find that the label merges, the evidence decisions and the long
scans' furniture stops share."""

from __future__ import annotations

import random

from ogscene3d._disjoint_sets import DisjointSets


def test_the_root_that_a_union_keeps_is_the_callers():
    sets = DisjointSets()
    assert not sets
    assert sets.find(7) == 7  # an id never attached is its own set
    assert sets.union(1, 2) == 2
    assert sets.union(3, 1) == 2  # 3 joins the set whose root is 2
    sets.attach(sets.find(5), sets.find(2))
    assert sets and [sets.find(v) for v in (1, 2, 3, 5)] == [2, 2, 2, 2]
    assert sets.groups() == {2: [1, 2, 3, 5]}
    sets.attach(4, 4)  # attaching a root to itself changes nothing
    assert 4 not in sets.parent


def test_sets_match_the_components_of_the_unions():
    rng = random.Random(0)
    edges = [(rng.randrange(40), rng.randrange(40)) for _ in range(30)]
    sets = DisjointSets()
    for a, b in edges:
        sets.union(a, b)
    # reference: flood fill over the same edges
    adj: dict[int, set[int]] = {}
    for a, b in edges:
        adj.setdefault(a, set()).add(b)
        adj.setdefault(b, set()).add(a)
    seen: dict[int, int] = {}
    for start in sorted(adj):
        if start in seen:
            continue
        stack = [start]
        while stack:
            v = stack.pop()
            if v not in seen:
                seen[v] = start
                stack.extend(adj[v] - seen.keys())
    for a in adj:
        for b in adj:
            assert (sets.find(a) == sets.find(b)) == (seen[a] == seen[b])
    touched = {v for a, b in edges if a != b for v in (a, b)}
    assert sorted(v for g in sets.groups().values() for v in g) == sorted(touched)
