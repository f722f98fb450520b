"""1-robust conflicts between two paths, each already expressed as its two CBS branches.

Two agents conflict when they are on the same cell at times at most one apart (DESIGN section 2:
vertex, following, swap and cycle conflicts are all of this form). A conflict is stored as
``(time, branch_i, branch_j)`` where each branch is ``(agent, constraints)`` and a constraint
``(cell, t0, t1)`` means "the agent may not be on the cell during [t0, t1]". Every valid plan
satisfies at least one branch and the current plan violates both, so splitting on them keeps
CBS complete and optimal:

* range conflict, agent i on v at ti and j on v at tj, ``|ti - tj| <= 1``, ``t0 = min(ti, tj)``:
  branches ``i: (v, t0, t0 + 1)`` and ``j: (v, t0, t0 + 1)``. A plan breaking both has i and j on
  v at two times of ``[t0, t0 + 1]``, which is itself a conflict.
* target conflict, i parked on its goal g from its cost ``T_i`` and j on g at ``tj >= T_i - 1``
  (``tj`` the last such time): branches ``i: (FINISH, tj + 1, tj + 1)`` (i arrives for good
  after ``tj + 1``; it may still pass over g earlier) and ``j: (g, tj, INF)`` (j never on g
  from ``tj`` on). If i's cost is at most ``tj + 1`` then i is on g from ``tj + 1`` for ever,
  and j on g at any time ``>= tj`` conflicts.
"""

from __future__ import annotations

from gateway.planning.constraints import FINISH, INF, Constraint
from gateway.planning.grid import Cell

Branch = tuple[int, tuple[Constraint, ...]]
"""``(agent, constraints)``: the constraints that one child of a split adds to that agent."""

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
            out.append((tj, (i, ((FINISH, tj + 1, tj + 1),)), (j, ((gi, tj, INF),))))
        ti = _last_visit(pi, gj)
        if ti >= tj_end - 1 and ti >= 0:
            out.append((ti, (j, ((FINISH, ti + 1, ti + 1),)), (i, ((gj, ti, INF),))))
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
            out.append((t0, (i, ((v, t0, t0 + 1),)), (j, ((v, t0, t0 + 1),))))
        prev_i = vi
        prev_j = vj
    return out


def _axis_direction(di: int, dj: int) -> int:
    """A common direction (+1/-1) of two moves along one axis, 0 if they disagree or both stay."""
    if di and dj:
        return di if di == dj else 0
    return di or dj


def rectangle(
    i: int, si: Cell, gi: Cell, j: int, sj: Cell, gj: Cell, width: int
) -> tuple[Branch, Branch] | None:
    """Barrier branches of a 1-robust rectangle conflict, or None if the geometry is not one.

    Precondition (the caller's): both agents' costs equal the Manhattan distances of their
    starts and goals, so every cheapest path is monotone and reaches cell c at ``tau(c) =
    |c - start|``. With both moving the same way along each axis (mirrored below to +x, +y),
    ``tau_i - tau_j`` is the same constant ``delta`` on every cell, and ``|delta| <= 1`` makes
    every shared cell a 1-robust conflict. If one agent's y-range lies inside the other's and
    the other's x-range inside the first's, the first ("h") crosses the rectangle
    ``R = [max sx, min gx] x [max sy, min gy]`` left to right and the second ("v") top to
    bottom. Branches: h is never on the exit column ``x = min gx`` at its on-time tau_h, or v
    is never on the exit row ``y = min gy`` at tau_v. A plan breaking both has h and v on
    monotone prefixes that cross R both ways, so they share a cell at times ``delta`` apart:
    a conflict. Hence every valid plan keeps one branch, and both raise their agent's cost.

    The ranges are widened by a slack ``w`` (``[tau, tau + w]``): a prefix reaching the barrier
    at most one step late is still monotone (a late arrival by one is one wait, by parity), and
    it meets the other prefix at a time difference in ``delta + [-w_v, w_h]``; with
    ``w_h = min(1, 1 - delta)`` and ``w_v = min(1, 1 + delta)`` that is still within one step.
    So a branch with ``w = 1`` raises its agent's cost by two.
    """
    dx = _axis_direction((gi[0] > si[0]) - (gi[0] < si[0]), (gj[0] > sj[0]) - (gj[0] < sj[0]))
    dy = _axis_direction((gi[1] > si[1]) - (gi[1] < si[1]), (gj[1] > sj[1]) - (gj[1] < sj[1]))
    if not dx or not dy:
        return None
    six, siy, gix, giy = dx * si[0], dy * si[1], dx * gi[0], dy * gi[1]
    sjx, sjy, gjx, gjy = dx * sj[0], dy * sj[1], dx * gj[0], dy * gj[1]
    delta = (sjx - six) + (sjy - siy)  # tau_i - tau_j on every cell
    if abs(delta) > 1:
        return None
    rsx, rsy, rgx, rgy = max(six, sjx), max(siy, sjy), min(gix, gjx), min(giy, gjy)
    if rsx > rgx or rsy > rgy:
        return None
    if siy >= sjy and giy <= gjy and sjx >= six and gjx <= gix:
        h, shx, shy, v, svx, svy, dh = i, six, siy, j, sjx, sjy, delta
    elif sjy >= siy and gjy <= giy and six >= sjx and gix <= gjx:
        h, shx, shy, v, svx, svy, dh = j, sjx, sjy, i, six, siy, -delta
    else:
        return None
    wh, wv = min(1, 1 - dh), min(1, 1 + dh)
    bar_h = tuple(
        (dy * y * width + dx * rgx, (rgx - shx) + (y - shy), (rgx - shx) + (y - shy) + wh)
        for y in range(rsy, rgy + 1)
    )
    bar_v = tuple(
        (dy * rgy * width + dx * x, (x - svx) + (rgy - svy), (x - svx) + (rgy - svy) + wv)
        for x in range(rsx, rgx + 1)
    )
    return (h, bar_h), (v, bar_v)
