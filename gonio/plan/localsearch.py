"""2-opt and Or-opt local search of a visiting order, in O(N log N)-like time on spread poses.

The order is an open path with a fixed first node and a free last one; :class:`gonio.plan.ordering._Graph`
closes it into a cycle through a start node ``S`` and a virtual end ``E`` (zero cost from everything),
so the local search works on a cycle and only has to keep the edge ``{S, E}``.

Moves (Croes 1958; Or 1976), searched the way Johnson & McGeoch describe for large instances ("The
traveling salesman problem: a case study in local optimization", 1997, §3.3 and §3.5; Bentley, "Fast
algorithms for geometric traveling salesman problems", ORSA J. Computing 4, 1992):

* **neighbour lists**: a move is only looked for where it adds an edge from a node to one of its ``k``
  nearest poses (by move time), and only while that edge is shorter than the one it replaces (the
  gain criterion: an improving 2-opt move adds an edge shorter than a removed one at one of its ends);
  the start (when fixed) and the virtual end are candidates of every pose;
* **don't-look bits**: a queue of the nodes whose surroundings changed; a node whose search finds no
  move leaves the queue until a move touches one of its tour neighbours;
* **array representation with the shorter side reversed**: a 2-opt move reverses whichever of the two
  paths it separates is shorter (both give the same cycle), with NumPy for long reversals;
* **Or-opt as 2-opt moves**: moving a segment of 1–3 poses between two others is two or three
  reversals, so one primitive keeps the positions consistent.

Each node's search takes the best move over its candidates (both tour directions, every segment of
length 1–3 with the node at an end). The move cost is the exact concurrent move time
(:meth:`gonio.plan.ordering.MotionModel.move_time`, evaluated in plain Python per pair, cached); a move
is applied only when it shortens the path by more than ``1e-9`` s, so the path never gets longer.
The search stops when the queue is empty, after ``max_passes × N`` node visits, or at ``deadline``.
"""

from __future__ import annotations

import time
from array import array
from collections import deque

import numpy as np

__all__ = ["improve", "reference_search"]

_EPS = 1e-9
_SHORT = 24  # reversals up to this length are done element by element (NumPy's call overhead dominates)


class _Tour:
    """A cycle in an array ``t`` (node at each position) with its inverse ``p`` (position of each node).

    ``array('q')`` gives fast scalar access from Python; NumPy views of the same memory do long
    reversals."""

    def __init__(self, nodes: np.ndarray):
        m = int(nodes.size)
        self.m = m
        self.t = array("q", np.asarray(nodes, dtype=np.int64).tobytes())
        self.p = array("q", bytes(8 * m))
        self.tn = np.frombuffer(self.t, dtype=np.int64)
        self.pn = np.frombuffer(self.p, dtype=np.int64)
        self.ar = np.arange(m)  # positions, for long reversals
        self.pn[self.tn] = self.ar

    def succ(self, x: int) -> int:
        i = self.p[x] + 1
        return self.t[0 if i == self.m else i]

    def pred(self, x: int) -> int:
        return self.t[self.p[x] - 1]

    def _reverse(self, i: int, n: int) -> None:
        """Reverse the ``n`` nodes at cyclic positions ``i, i+1, ..., i+n-1``."""
        m, t, p = self.m, self.t, self.p
        if n <= _SHORT:
            lo, hi = i, i + n - 1
            while lo < hi:
                a, b = lo % m, hi % m
                x, y = t[a], t[b]
                t[a] = y
                p[y] = a
                t[b] = x
                p[x] = b
                lo += 1
                hi -= 1
            return
        if i + n <= m:
            seg = self.tn[i:i + n]
            seg[:] = seg[::-1]  # NumPy copies an overlapping source first
            self.pn[seg] = self.ar[i:i + n]
        else:
            idx = np.arange(i, i + n) % m
            seg = self.tn[idx][::-1]
            self.tn[idx] = seg
            self.pn[seg] = idx

    def two_opt(self, a: int, b: int, c: int, d: int) -> None:
        """Replace edges ``{a, b}`` and ``{c, d}`` by ``{a, c}`` and ``{b, d}``.

        Either ``b = succ(a)`` and ``d = succ(c)``, or ``b = pred(a)`` and ``d = pred(c)``."""
        if self.succ(a) != b:  # the pred case is the succ case read from the other ends
            a, b, c, d = b, a, d, c
        # the path b ... c (forward) or, equally, d ... a: reverse the shorter
        i, j = self.p[b], self.p[c]
        n = (j - i) % self.m + 1
        if 2 * n > self.m:
            i, n = self.p[d], self.m - n
        if n > 1:
            self._reverse(i, n)

    def order(self) -> np.ndarray:
        return self.tn.copy()


def improve(nodes: np.ndarray, cost, nbr_idx: list[list[int]], nbr_cost: list[list[float]], n_poses: int,
            fixed_start: bool, *, max_passes: int = 30, deadline: float = float("inf"),
            progress=None) -> np.ndarray:
    """2-opt + Or-opt local search of the cycle ``nodes`` (poses ``0..N-1``, start ``N``, virtual end
    ``N+1``); returns the improved cycle, rotated so that it starts ``N`` and ends ``N+1``.

    ``cost(a, b)``: move time between nodes (0 to or from a virtual node); ``nbr_idx[a]``/``nbr_cost[a]``:
    candidate neighbours of node ``a``, nearest first, with their costs (every node has a list, the end
    node's may be empty). ``progress``: called with the number of node visits done so far, now and then.
    """
    tour = _Tour(np.asarray(nodes, dtype=np.int64))
    m = tour.m
    S, E = n_poses, n_poses + 1
    t, p = tour.t, tour.p
    succ, pred = tour.succ, tour.pred
    # the start (fixed: a real pose, cost from the list; free: virtual, 0) and the virtual end are
    # candidates of every pose, ahead of its neighbours (the lists are read in increasing cost)
    cand_i: list[list[int]] = []
    cand_c: list[list[float]] = []
    for a in range(m):
        row_i, row_c = list(nbr_idx[a]), list(nbr_cost[a])
        if a == E:
            row_i, row_c = [], []
        elif a == S:
            row_i, row_c = [E] + row_i, [0.0] + row_c
        elif fixed_start:
            ca = cost(a, S)
            k = 0
            while k < len(row_c) and row_c[k] < ca:
                k += 1
            row_i, row_c = [E] + row_i[:k] + [S] + row_i[k:], [0.0] + row_c[:k] + [ca] + row_c[k:]
        else:
            row_i, row_c = [S, E] + row_i, [0.0, 0.0] + row_c
        cand_i.append(row_i)
        cand_c.append(row_c)

    def best_two_opt(a: int):
        best, move = _EPS, None
        pa = p[a]
        for fwd in (True, False):
            b = t[pa + 1 if pa + 1 < m else 0] if fwd else t[pa - 1]
            if a >= S and b >= S:
                continue  # the edge {S, E} stays
            g = cost(a, b)
            for c, dac in zip(cand_i[a], cand_c[a]):
                if dac >= g - best:
                    break  # gain criterion; lists are sorted
                pc = p[c]
                d = t[pc + 1 if pc + 1 < m else 0] if fwd else t[pc - 1]
                if c == b or d == a or (c >= S and d >= S):
                    continue
                delta = g + cost(c, d) - dac - cost(b, d)
                if delta > best:
                    best, move = delta, (a, b, c, d)
        return best, move

    def best_or_opt(a: int):
        best, move = _EPS, None
        if a >= S:
            return best, move
        a1, b1 = succ(a), pred(a)
        a2, b2 = succ(a1), pred(b1)
        segments = [([a], b1, a1), ([a, a1], b1, a2), ([b1, a], b2, a1),
                    ([a, a1, a2], b1, succ(a2)), ([b2, b1, a], pred(b2), a1)]
        for seg, prv, nxt in segments:
            if seg[0] >= S or seg[-1] >= S or seg[len(seg) // 2] >= S:
                continue  # only poses move
            if prv == nxt or prv in seg or nxt in seg:
                continue  # the segment is (almost) the whole tour
            s1, sl = seg[0], seg[-1]
            gain = cost(prv, s1) + cost(sl, nxt) - cost(prv, nxt)
            if gain <= best:
                continue
            for e, o in ((s1, sl), (sl, s1)) if s1 != sl else ((s1, s1),):
                for c, dec in zip(nbr_idx[e], nbr_cost[e]):
                    if dec >= gain - best:
                        break
                    if c in seg:
                        continue
                    pc = p[c]
                    for v in (t[pc + 1 if pc + 1 < m else 0], t[pc - 1]):
                        if v in seg or (c >= S and v >= S):
                            continue
                        delta = gain - (dec + cost(o, v) - cost(c, v))
                        if delta > best:
                            best, move = delta, (seg, prv, nxt, c, v, e)
        return best, move

    def apply_or_opt(seg, prv, nxt, c, v, e):
        s1, sl = seg[0], seg[-1]
        # the insertion edge as (u, w) with w = succ(u), and whether s1 follows u
        if v == succ(c):
            u, w, forward = c, v, e == s1
        else:
            u, w, forward = v, c, e != s1
        two = tour.two_opt
        if w == prv:  # u prv S nxt -> u S^r prv nxt
            two(u, prv, sl, nxt)
            if forward and len(seg) > 1:
                two(u, sl, s1, prv)
        elif u == nxt:  # prv S nxt w -> prv nxt S^r w
            two(prv, s1, nxt, w)
            if forward and len(seg) > 1:
                two(nxt, sl, s1, w)
        else:  # prv S nxt..u w -> prv u..nxt S^r w -> prv nxt..u S^r w
            two(prv, s1, u, w)
            two(prv, u, nxt, sl)
            if forward and len(seg) > 1:
                two(u, sl, s1, w)
        return [prv, nxt, u, w, s1, sl]

    queued = bytearray(m)
    queue: deque[int] = deque()
    for x in tour.t:
        if x != E:
            queue.append(x)
            queued[x] = 1
    visits, budget = 0, max(1, int(max_passes * m))
    while queue and visits < budget:
        visits += 1
        if visits & 1023 == 0:
            if time.perf_counter() > deadline:
                break
            if progress is not None:
                progress(visits)
        a = queue.popleft()
        queued[a] = 0
        g2, m2 = best_two_opt(a)
        g3, m3 = best_or_opt(a)
        if m2 is None and m3 is None:
            continue
        if m3 is None or (m2 is not None and g2 >= g3):
            tour.two_opt(*m2)
            touched = list(m2)
        else:
            touched = apply_or_opt(*m3)
        for x in [a] + touched:
            if x != E and not queued[x]:
                queued[x] = 1
                queue.append(x)
    out = tour.order()
    # rotate to start at S; the cycle keeps {S, E}, so E is S's neighbour on one side
    k = int(p[S])
    out = np.roll(out, -k)
    if out[1] == E:
        out = np.concatenate([out[:1], out[1:][::-1]])
    assert out[-1] == E
    return out


def reference_search(cost, tour: np.ndarray, nbrs: list[list[int]], deadline: float, max_passes: int) -> None:
    """The previous local search, kept as the reference of tests and ``benchmarks/bench_plan.py``:
    2-opt and Or-opt (segments of 1-3) over neighbour lists, in place, on a Python list whose ends
    (``tour[0]`` the start node, ``tour[-1]`` the free end) stay in place; a pass visits every pose and
    a 2-opt move reverses the positions between its edges, so a move costs O(N) and a pass O(N²) on
    large sets."""
    m = tour.size
    pos = np.empty(m, np.int64)
    pos[tour] = np.arange(m)
    t = tour.tolist()
    p = pos.tolist()

    def two_opt(i: int, j: int) -> bool:
        # edges (t[i], t[i+1]) and (t[j], t[j+1]) -> (t[i], t[j]) and (t[i+1], t[j+1]); reverse t[i+1..j]
        if i < 0 or j > m - 2 or j <= i + 1:
            return False
        a, b, c, d = t[i], t[i + 1], t[j], t[j + 1]
        if cost(a, b) + cost(c, d) - cost(a, c) - cost(b, d) <= 1e-9:
            return False
        t[i + 1:j + 1] = t[i + 1:j + 1][::-1]
        for k in range(i + 1, j + 1):
            p[t[k]] = k
        return True

    def or_opt(i: int, seg_len: int) -> bool:
        # move t[i .. i+seg_len-1] between two poses next to a neighbour of one of its ends
        if i < 1 or i + seg_len > m - 1:
            return False
        s0, s1, prv, nxt = t[i], t[i + seg_len - 1], t[i - 1], t[i + seg_len]
        removal = cost(prv, s0) + cost(s1, nxt) - cost(prv, nxt)
        if removal <= 1e-9:
            return False
        best, best_k, best_rev = 1e-9, -1, False
        for end, other in ((s0, s1), (s1, s0)):
            for c in nbrs[end]:
                dce = cost(c, end)
                if dce >= removal:
                    break  # neighbours are sorted: no closer one left
                pc = p[c]
                # `end` right after c (edge k = pc), or right before c (edge k = pc - 1)
                for k, u_is_c in ((pc, True), (pc - 1, False)):
                    if k < 0 or k > m - 2 or i - 1 <= k <= i + seg_len - 1:
                        continue
                    u, v = t[k], t[k + 1]
                    if u_is_c:
                        add = dce + cost(other, v) - cost(u, v)
                    else:
                        add = cost(u, other) + dce - cost(u, v)
                    if removal - add > best:
                        # u_is_c and end == s0 -> forward; u_is_c and end == s1 -> reversed, etc.
                        best, best_k, best_rev = removal - add, k, (end == s0) != u_is_c
                if seg_len == 1:
                    pass
            if seg_len == 1:
                break
        if best_k < 0:
            return False
        seg = t[i:i + seg_len]
        if best_rev:
            seg.reverse()
        del t[i:i + seg_len]
        k = best_k if best_k < i else best_k - seg_len
        t[k + 1:k + 1] = seg
        lo, hi = min(i, k + 1), max(i + seg_len, k + 1 + seg_len)
        for kk in range(lo, hi):
            p[t[kk]] = kk
        return True

    n_real = m - 2
    for _ in range(max_passes):
        improved = False
        for node in range(n_real):
            if time.perf_counter() > deadline:
                break
            for c in nbrs[node]:
                pa, pc = p[node], p[c]
                d_ac = cost(node, c)
                if d_ac >= max(cost(node, t[pa + 1]), cost(t[pa - 1], node) if pa > 0 else 0.0):
                    break  # a 2-opt gain needs a new edge shorter than one it removes at `node`
                lo, hi = min(pa, pc), max(pa, pc)
                if two_opt(lo, hi) or two_opt(lo - 1, hi - 1):
                    improved = True
            pa = p[node]
            improved = two_opt(0, pa - 1) | two_opt(pa, m - 2) | improved
            for seg_len in (1, 2, 3):
                if or_opt(p[node], seg_len):
                    improved = True
        if not improved or time.perf_counter() > deadline:
            break
    tour[:] = t


