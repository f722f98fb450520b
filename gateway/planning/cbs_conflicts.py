"""1-robust conflicts between two paths, each already expressed as its two CBS branches.

Two agents conflict when they are on the same cell at times at most one apart (DESIGN section 2:
vertex, following, swap and cycle conflicts are all of this form). A conflict is stored as
``(time, branch_i, branch_j)`` where each branch is ``(agent, cell, t0, t1)``: "agent may not be
on cell during [t0, t1]". Every valid plan satisfies at least one branch and the current plan
violates both, so splitting on them keeps CBS complete and optimal:

* range conflict, agent i on v at ti and j on v at tj, ``|ti - tj| <= 1``, ``t0 = min(ti, tj)``:
  branches ``(i, v, t0, t0 + 1)`` and ``(j, v, t0, t0 + 1)``. A plan breaking both has i and j on
  v at two times of ``[t0, t0 + 1]``, which is itself a conflict.
* target conflict, i parked on its goal g from its cost ``T_i`` and j on g at ``tj >= T_i - 1``
  (``tj`` the last such time): branches ``(i, g, tj + 1, tj + 1)`` (i arrives for good after
  ``tj + 1``) and ``(j, g, tj, INF)`` (j never on g from ``tj`` on). If i's cost is at most
  ``tj + 1`` then i is on g from ``tj + 1`` for ever, and j on g at any time ``>= tj`` conflicts.
"""

from __future__ import annotations

from gateway.planning.constraints import INF

Branch = tuple[int, int, int, int]
"""``(agent, cell, t0, t1)``: the agent may not be on the cell during ``[t0, t1]``."""

Conflict = tuple[int, Branch, Branch]
"""``(time, branch_i, branch_j)``."""


def _last_visit(path: tuple[int, ...], cell: int) -> int:
    """Last index at which ``path`` is on ``cell`` (-1 if never)."""
    for t in range(len(path) - 1, -1, -1):
        if path[t] == cell:
            return t
    return -1


def pair_conflicts(
    i: int, pi: tuple[int, ...], j: int, pj: tuple[int, ...], target: bool
) -> list[Conflict]:
    """All conflicts between agents i and j (cell paths, each ending on its goal for good).

    With ``target`` the conflicts that involve an agent parked on its goal become one target
    conflict per parked agent; otherwise they are range conflicts like the others.
    """
    if set(pi).isdisjoint(pj):
        return []
    ti_end = len(pi) - 1
    tj_end = len(pj) - 1
    gi = pi[-1]
    gj = pj[-1]
    out: list[Conflict] = []
    if target:
        tj = _last_visit(pj, gi)
        if tj >= ti_end - 1 and tj >= 0:
            out.append((tj, (i, gi, tj + 1, tj + 1), (j, gi, tj, INF)))
        ti = _last_visit(pi, gj)
        if ti >= tj_end - 1 and ti >= 0:
            out.append((ti, (j, gj, ti + 1, ti + 1), (i, gj, ti, INF)))
    seen: set[tuple[int, int]] = set()
    prev_i = pi[0]
    prev_j = pj[0]
    for t in range(max(ti_end, tj_end) + 1):
        vi = pi[t] if t <= ti_end else gi
        vj = pj[t] if t <= tj_end else gj
        events = []
        if vi == vj:
            events.append((vi, t, t))
        if t:
            if vi == prev_j:
                events.append((vi, t, t - 1))
            if vj == prev_i:
                events.append((vj, t - 1, t))
        for v, ta, tb in events:
            if target and (ta >= ti_end or tb >= tj_end):
                continue  # an agent parked on its goal: covered by the target conflict
            t0 = min(ta, tb)
            if (v, t0) in seen:
                continue
            seen.add((v, t0))
            out.append((t0, (i, v, t0, t0 + 1), (j, v, t0, t0 + 1)))
        prev_i = vi
        prev_j = vj
    return out
