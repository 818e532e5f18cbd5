"""Exact nearest neighbours and minimum spanning tree of poses under the concurrent move-time metric,
in O(N log N) with a k-d tree (:class:`scipy.spatial.cKDTree`).

Move time is ``t(a, b) = max_j t_j(|Δq_j|)`` with ``t_j`` the trapezoidal profile of
:func:`gonio.rig.kinematics.trapezoid_time`. It is not a norm, but it is bounded below by a monotone
function of the Chebyshev distance of the joints scaled by their speeds, ``x = max_j |Δq_j| / v_j``:

    t_j(d) ≥ d / v_j,   so   t(a, b) ≥ F(x),   F(x) = min_j t_j(x · v_j)   (monotone)

(``2√(d/a) ≥ d/v`` for ``d ≤ v²/a`` and ``d/v + v/a ≥ d/v``; Biagiotti & Melchiorri 2008, §3.2.2).
Every point that a Chebyshev k-nearest query did not return lies at Chebyshev distance ≥ the last one
returned, hence at move time ≥ ``F`` of it: a candidate list whose k-th exact time is ≤ that is the
exact k-nearest list, otherwise the query is repeated with more candidates. When all joints share
``v/a`` (the default rig), ``t = F(x)`` exactly and the first query almost always suffices.

The spanning tree is Borůvka's (Borůvka 1926; Nešetřil et al., "Otakar Borůvka on minimum spanning tree
problem", 2001): each round joins every component to its nearest other component. A component's
cheapest outgoing edge is read from its points' exact neighbour lists when it is provably minimal
(no point's unlisted neighbours can be closer), otherwise by a vectorized scan of those points against
all others. Any cheapest outgoing edge may be taken per component (ties need no consistent rule when
cycles are skipped with a union-find), so the weight is the exact MST weight, as Prim's O(N²) gives.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["supported", "knn", "mst_weight", "remember", "recall", "NearestUnvisited"]

_TWO_PI = 2.0 * math.pi


def supported(model) -> bool:
    """True when the k-d tree bound applies (finite positive speeds and accelerations)."""
    return bool(np.all(np.isfinite(model.vmax)) and np.all(np.isfinite(model.amax)))


def _floor(model, x: np.ndarray) -> np.ndarray:
    """``F(x) = min_j t_j(x · v_j)``: a lower bound of the move time at scaled Chebyshev distance ``x``."""
    from gonio.rig.kinematics import trapezoid_time

    x = np.asarray(x, dtype=np.float64)
    return trapezoid_time(x[..., None] * model.vmax, model.vmax, model.amax).min(axis=-1)


#: Point sets up to this size are searched exhaustively (:class:`_Exhaustive`) instead of with a k-d tree: the
#: plans a session orders are mostly this small (the default in-plane plan has 56 poses), and importing
#: scipy.spatial alone costs ~0.4 CPU s, more than exhaustive queries of every pose of such a plan.
EXHAUSTIVE_MAX = 256


class _Exhaustive:
    """The queries of :class:`scipy.spatial.cKDTree` that this module makes (Chebyshev distance, ``p=inf``,
    periodic ``boxsize``), answered by comparing with every point: the ``k`` nearest points (distance, index),
    nearest first (ties by index), the missing ones (beyond ``distance_upper_bound`` or past the point count)
    as ``inf`` and index ``n``, shaped as cKDTree shapes them. ``indices`` is the points' order, as the tree's
    leaf order (any order gives the same lists, :func:`_query`)."""

    def __init__(self, data: np.ndarray, boxsize=None):
        self.data = np.asarray(data, dtype=np.float64)
        self.n = self.data.shape[0]
        self.box = None if boxsize is None else np.asarray(boxsize, dtype=np.float64)
        self.indices = np.arange(self.n)

    def query(self, x, k: int = 1, p: float = np.inf, distance_upper_bound: float = np.inf):
        assert p == np.inf, "only the Chebyshev distance is needed here"
        x = np.asarray(x, dtype=np.float64)
        q = x.reshape(-1, self.data.shape[1])
        diff = np.abs(q[:, None, :] - self.data[None, :, :])
        if self.box is not None:
            diff = np.minimum(diff, self.box - diff)
        d = diff.max(axis=-1) if self.n else np.zeros((q.shape[0], 0))
        order = np.argsort(d, axis=1, kind="stable")[:, :k]
        dist = np.take_along_axis(d, order, 1)
        far = dist > distance_upper_bound
        dist[far], order[far] = np.inf, self.n
        if order.shape[1] < k:  # fewer points than k: cKDTree pads with inf and index n
            pad = k - order.shape[1]
            dist = np.concatenate([dist, np.full((q.shape[0], pad), np.inf)], axis=1)
            order = np.concatenate([order, np.full((q.shape[0], pad), self.n)], axis=1)
        shape = x.shape[:-1] + ((k,) if k > 1 else ())
        return dist.reshape(shape), order.reshape(shape)


def _tree(x: np.ndarray, model, ref: np.ndarray):
    """k-d tree over ``x`` in speed-scaled coordinates (periodic on wrap joints; non-wrap axes offset
    and boxed by the extent of ``ref``, a superset of every point queried, so they never wrap); up to
    :data:`EXHAUSTIVE_MAX` points an exhaustive search with the same answers (:class:`_Exhaustive`)."""
    s = _scaled_like(x, ref, model)
    box = None
    if model.wrap.any():
        r = _scaled_like(ref, ref, model)
        box = np.where(model.wrap, _TWO_PI / model.vmax, np.ptp(r, axis=0) * 4.0 + 1.0)
    if s.shape[0] <= EXHAUSTIVE_MAX:
        return _Exhaustive(s, boxsize=box)
    from scipy.spatial import cKDTree

    return cKDTree(s, boxsize=box)


def _query(q: np.ndarray, model, targets: np.ndarray, sources: np.ndarray, k: int, chunk: int = 4096):
    """The ``k`` exact nearest of ``targets`` (pose indices) to each of ``sources`` (pose indices),
    excluding the source itself: ``(index, time)`` each ``(len(sources), k)``, nearest first (ties by
    index). ``k`` must be ≤ the targets available to each source.

    Sources are queried in chunks (temporaries that stay in cache) and, when they are the targets, in the
    k-d tree's leaf order (neighbouring queries walk the same nodes): each row's result is the same as
    from one batch in any order, at 10⁵ poses in about half the time."""
    m = targets.size
    tree = _tree(q[targets], model, q)
    sq = _scaled_like(q[sources], q, model)
    ns = sources.size
    idx = np.zeros((ns, k), np.int64)
    dist = np.zeros((ns, k))
    same = sources is targets or (ns == m and np.array_equal(sources, targets))
    walk = tree.indices if same else np.arange(ns)
    for lo in range(0, ns, chunk):
        todo = walk[lo:lo + chunk]
        kk = min(m, 2 * k + 2)
        while todo.size:
            cheb, cand = tree.query(sq[todo], k=kk, p=np.inf)
            cand = targets[cand.reshape(todo.size, kk)]
            cheb = cheb.reshape(todo.size, kk)
            src = sources[todo]
            t = model.move_time(q[src][:, None, :], q[cand])
            t[cand == src[:, None]] = np.inf  # not its own neighbour
            o = np.lexsort((cand, t), axis=-1)[:, :k]
            ci = np.take_along_axis(cand, o, 1)
            ct = np.take_along_axis(t, o, 1)
            ok = (ct[:, -1] <= _floor(model, cheb[:, -1])) | (kk >= m)
            idx[todo[ok]] = ci[ok]
            dist[todo[ok]] = ct[ok]
            todo = todo[~ok]
            kk = min(m, kk * 2)
    return idx, dist


def _scaled_like(x: np.ndarray, ref: np.ndarray, model) -> np.ndarray:
    """``x`` in the scaled coordinates of :func:`_tree` built over ``ref``."""
    s = x / model.vmax
    if model.wrap.any():
        s = s.copy()
        period = _TWO_PI / model.vmax
        s[:, model.wrap] = np.mod(s[:, model.wrap], period[model.wrap])
        s[:, ~model.wrap] -= (ref / model.vmax)[:, ~model.wrap].min(axis=0)
    return s


def knn(q: np.ndarray, model, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest other poses of every pose by exact move time: ``(index, time)`` each ``(N, k)``,
    nearest first (ties by index)."""
    n = q.shape[0]
    k = min(k, n - 1)
    if k <= 0:
        return np.zeros((n, 0), np.int64), np.zeros((n, 0))
    every = np.arange(n)
    return _query(q, model, every, every, k)


#: The last neighbour lists :func:`remember` was given: ``(key, (index, time))``. Ordering a plan builds
#: them (:func:`gonio.plan.ordering.optimize_order`) and its estimate's spanning tree needs them again
#: (:func:`gonio.plan.ordering.mst_move_time`, ~1.3 CPU-s at 10⁵ poses): one entry, ~16 MB at 10⁵ poses.
_LAST: list = []


def _key(q: np.ndarray, model) -> tuple:
    """Content key of a pose set under a motion model (a hash of the bytes: a plan's joints are a copy)."""
    import hashlib

    q = np.ascontiguousarray(q, dtype=np.float64)
    h = hashlib.blake2b(q.tobytes(), digest_size=16)
    for arr in (model.vmax, model.amax, model.wrap):
        h.update(np.ascontiguousarray(arr).tobytes())
    return q.shape, h.digest()


def remember(q: np.ndarray, model, nbrs: tuple[np.ndarray, np.ndarray]) -> None:
    """Keep the exact neighbour lists ``nbrs`` of the rows of ``q`` (as :func:`knn` returns them) for
    :func:`recall`; only the last set is kept."""
    _LAST[:] = [(_key(q, model), nbrs)]


def recall(q: np.ndarray, model):
    """The lists :func:`remember` kept for exactly these rows of ``q`` under ``model``, or None."""
    if not _LAST:
        return None
    key, nbrs = _LAST[0]
    return nbrs if key == _key(q, model) else None


def _find(parent: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Roots of ``x`` in the union-find forest ``parent`` (vectorized pointer jumping)."""
    r = parent[x]
    while True:
        rr = parent[r]
        if np.array_equal(rr, r):
            return r
        r = rr


def mst_weight(q: np.ndarray, model, k: int = 12, nbrs=None) -> float:
    """Exact weight of the minimum spanning tree of the rows of ``q`` under concurrent move time
    (Borůvka rounds over exact k-nearest lists; see the module docstring)."""
    n = q.shape[0]
    if n < 2:
        return 0.0
    from gonio.progress import progress_counter

    with progress_counter(total=n - 1, desc="lower bound (spanning tree)", unit="edge", delay=2.0) as tick:
        idx, dist = nbrs if nbrs is not None else knn(q, model, k)
        return _boruvka(q, model, idx, dist, tick)


def _boruvka(q: np.ndarray, model, idx: np.ndarray, dist: np.ndarray, tick) -> float:
    """Borůvka's rounds of :func:`mst_weight` over the lists ``idx``/``dist``; ``tick(edges joined)``."""
    n = q.shape[0]
    rk = dist[:, -1] if dist.shape[1] else np.full(n, 0.0)
    parent = np.arange(n)
    total = 0.0
    joined = 0
    rows = np.arange(n)
    shared = None  # a k-d tree over all poses, built when a component's lists never leave it
    while joined < n - 1:
        tick(joined)
        lab = _find(parent, rows)
        parent = lab.copy()
        outside = lab[idx] != lab[:, None]
        has = outside.any(axis=1)
        first = outside.argmax(axis=1)
        cd = np.where(has, dist[rows, first], np.inf)
        cv = idx[rows, first]
        # per component: cheapest listed outgoing edge, and the bound below which unlisted edges may lie
        comp_best = np.full(n, np.inf)
        np.minimum.at(comp_best, lab, cd)
        bound = np.full(n, np.inf)
        np.minimum.at(bound, lab[~has], rk[~has])
        roots = np.unique(lab)
        unresolved = roots[comp_best[roots] > bound[roots]]
        edges_u, edges_v, edges_w = [], [], []
        # every component's cheapest listed edge: the row that reached comp_best
        sel = np.flatnonzero(has & (cd <= comp_best[lab]))
        _, first_of = np.unique(lab[sel], return_index=True)
        sel = sel[first_of]
        open_ = np.zeros(n, bool)
        open_[unresolved] = True
        done = ~open_[lab[sel]]  # resolved: the listed edge is the cheapest
        edges_u.append(sel[done])
        edges_v.append(cv[sel[done]])
        edges_w.append(cd[sel[done]])
        if unresolved.size:
            if shared is None:
                shared = (_tree(q, model, q), _scaled_like(q, q, model))
            # unresolved: only members none of whose listed neighbours leaves the component and whose
            # unlisted ones (≥ rk) may beat the listed edge can hold a cheaper one (a member with an
            # outside neighbour listed has its nearest outside pose listed: the lists are exact)
            members = np.flatnonzero(open_[lab] & ~has & (rk < comp_best[lab]))
            seed = sel[~done]
            eu, ev, ew = _outgoing(q, model, lab, unresolved, *shared, 2 * idx.shape[1] + 2, members=members,
                                   seed=(seed, cv[seed], cd[seed]))
            edges_u.append(eu)
            edges_v.append(ev)
            edges_w.append(ew)
        eu = np.concatenate(edges_u)
        ev = np.concatenate(edges_v)
        ew = np.concatenate(edges_w)
        for u, v, w in zip(eu.tolist(), ev.tolist(), ew.tolist()):
            ru, rv = u, v
            while parent[ru] != ru:
                ru = parent[ru]
            while parent[rv] != rv:
                rv = parent[rv]
            if ru != rv:
                parent[max(ru, rv)] = min(ru, rv)
                total += w
                joined += 1
    return total


def _radius(model, w: float) -> float:
    """The scaled Chebyshev distance beyond which every move takes longer than ``w`` (the inverse of
    :func:`_floor`: ``F(x) ≤ w`` iff some joint's ``t_j(x v_j) ≤ w``), slightly widened; inf for inf."""
    if not np.isfinite(w):
        return np.inf
    v, a = model.vmax, model.amax
    d = np.where(w <= 2.0 * v / a, (w / 2.0) ** 2 * a, (w - v / a) * v)  # t_j(d) = w, per joint
    return float(np.max(d / v)) * (1.0 + 1e-9) + 1e-12


def _outgoing(q: np.ndarray, model, lab: np.ndarray, comps: np.ndarray, tree, sq: np.ndarray, k0: int,
              kmax: int = 64, chunk: int = 4096, members: np.ndarray | None = None, seed=None):
    """The cheapest edge from each component in ``comps`` (labels ``lab``) to another component, exactly:
    ``(u, v, w)`` arrays, one edge per component.

    ``members``: the poses that may hold a cheaper edge than ``seed`` (``(u, v, w)`` arrays of known
    edges out of some of the components; default: every member of ``comps``, no known edge). Every
    member is queried in the k-d tree over all poses for its ``kk`` nearest (kk doubling): its
    nearest pose of another component is exact once found at a time ≤ the floor of the last returned
    distance (module docstring); a member stops early when that floor already reaches its component's
    cheapest edge so far (it cannot beat it). Members still open at ``kk > kmax`` (deep inside a large
    component) are resolved by a k-d tree over the other components' poses."""
    n = q.shape[0]
    comp_w = np.full(n, np.inf)
    comp_u = np.zeros(n, np.int64)
    comp_v = np.zeros(n, np.int64)

    def offer(u, v, w):
        o = np.argsort(-w, kind="stable")  # fancy assignment keeps the last: the cheapest
        u, v, w = u[o], v[o], w[o]
        better = w < comp_w[lab[u]]
        u, v, w = u[better], v[better], w[better]
        comp_w[lab[u]], comp_u[lab[u]], comp_v[lab[u]] = w, u, v

    if seed is not None and seed[0].size:
        offer(*(np.asarray(a) for a in seed))
    todo = np.flatnonzero(np.isin(lab, comps)) if members is None else np.asarray(members, dtype=np.int64)
    kk = min(n, k0)
    while todo.size and kk <= kmax:
        keep = []
        for lo in range(0, todo.size, chunk):
            rows = todo[lo:lo + chunk]
            cheb, cand = tree.query(sq[rows], k=kk, p=np.inf)
            cand = cand.reshape(rows.size, kk)
            t = model.move_time(q[rows][:, None, :], q[cand])
            t[lab[cand] == lab[rows][:, None]] = np.inf
            j = t.argmin(axis=1)
            w = t[np.arange(rows.size), j]
            ok = np.isfinite(w)
            offer(rows[ok], cand[np.arange(rows.size), j][ok], w[ok])
            floor = _floor(model, cheb.reshape(rows.size, kk)[:, -1])
            keep.append((rows, w, floor))
        if kk >= n:
            todo = todo[:0]
            break
        # open: the nearest other-component pose may be unlisted and cheaper than the component's best
        todo = np.concatenate([r[(w > f) & (f < comp_w[lab[r]])] for r, w, f in keep])
        kk = min(n, kk * 2)
    for c in np.unique(lab[todo]):
        # members deep inside a large component: a k-d tree over the other components' poses, searched
        # only within the radius where an edge could beat the component's best so far
        members = todo[lab[todo] == c]
        others = np.flatnonzero(lab != c)
        r = _radius(model, comp_w[c])
        if np.isfinite(r) and not model.wrap.any():
            # only poses within r of the members' bounding box can beat the best so far (a move to one
            # farther away takes longer, see _radius): on dense grids a small part of the others
            ms = sq[members]
            so = sq[others]
            others = others[np.all((so >= ms.min(axis=0) - r) & (so <= ms.max(axis=0) + r), axis=1)]
            if not others.size:
                continue
        sub = _tree(q[others], model, q)
        kq = min(others.size, 8)
        cheb, j = sub.query(sq[members], k=kq, p=np.inf, distance_upper_bound=r)
        cheb, j = cheb.reshape(members.size, kq), j.reshape(members.size, kq)
        found = j < others.size
        jj = others[np.where(found, j, 0)]
        t = np.where(found, model.move_time(q[members][:, None, :], q[jj]), np.inf)
        best = t.argmin(axis=1)
        w = t[np.arange(members.size), best]
        # exact when every pose within the radius was listed, or the best beats the floor of the last
        exact = ~found[:, -1] | (w <= _floor(model, cheb[:, -1]))
        ok = np.isfinite(w)
        offer(members[ok], jj[np.arange(members.size), best][ok], w[ok])
        rest = members[~exact]
        if rest.size:
            j1, t1 = _query(q, model, others, rest, 1)
            offer(rest, j1[:, 0], t1[:, 0])
    return comp_u[comps], comp_v[comps], comp_w[comps]


class NearestUnvisited:
    """Exact nearest unvisited pose by move time (ties: lowest index), for a greedy tour: the pose's
    k-nearest list first, then k-d tree queries on a tree rebuilt over the unvisited poses when half of
    its points have been visited. Amortized O(log N) per step on well-spread poses."""

    def __init__(self, q: np.ndarray, model, nbrs):
        self.q, self.model = q, model
        self.idx, self.dist = nbrs
        self.unvisited = np.ones(q.shape[0], bool)
        self._build(np.arange(q.shape[0]))

    def _build(self, ids: np.ndarray):
        self.ids = ids
        self.tree = _tree(self.q[ids], self.model, self.q) if ids.size else None
        self.live = ids.size

    def visit(self, i: int) -> None:
        self.unvisited[i] = False
        self.live -= 1
        if self.ids.size >= 64 and self.live * 2 < self.ids.size:
            self._build(np.flatnonzero(self.unvisited))

    def nearest_to(self, i: int) -> int:
        row_i, row_d = self.idx[i], self.dist[i]
        free = self.unvisited[row_i]
        if free.any() and row_d.size:
            j = int(np.argmax(free))
            if row_d[j] < row_d[-1]:
                return int(row_i[j])
        return self.nearest_point(self.q[i])

    def nearest_point(self, x: np.ndarray) -> int:
        """The unvisited pose nearest joint vector ``x`` (ties: lowest index); -1 if none is left."""
        ids = self.ids
        m = ids.size
        kk = min(m, 16)
        s = _scaled_like(np.asarray(x, dtype=np.float64)[None, :], self.q, self.model)[0]
        while m:
            cheb, cand = self.tree.query(s, k=kk, p=np.inf)
            cand = np.atleast_1d(cand)
            cheb = np.atleast_1d(cheb)
            g = ids[cand]
            ok = self.unvisited[g]
            if ok.any():
                g = g[ok]
                t = self.model.move_time(x[None, :], self.q[g])
                best = t.min()
                if kk >= m or best < float(_floor(self.model, cheb[-1])):
                    return int(g[t == best].min())
            if kk >= m:
                break
            kk = min(m, kk * 4)
        return -1
