"""Order the poses of a plan for lab time, and estimate that time with a lower bound.

Lab-time model
--------------
A pose costs a fixed time (settle + capture, :meth:`gonio.plan.plan.CaptureSettings.pose_time`) plus
the move that reaches it. Joints move concurrently, each under a trapezoidal velocity profile with its
own speed and acceleration limits, so a move lasts as long as its slowest joint:

    t_j(d) = 2 √(d / a_j)              if d ≤ v_j² / a_j   (triangular profile, v_j never reached)
    t_j(d) = d / v_j + v_j / a_j       otherwise           (accelerate, cruise, decelerate)
    t_move = max_j t_j(|Δq_j|)

(Biagiotti & Melchiorri, *Trajectory Planning for Automatic Machines and Robots*, Springer 2008,
§3.2.2, trapezoidal velocity profile with zero boundary velocities; the profile the Dynamixel servos
run, :func:`gonio.rig.kinematics.trapezoid_time`, which :class:`MotionModel` calls.) For a continuous-rotation joint
(``wrap``) Δq is the shorter way round the circle.

Ordering
--------
Finding the cheapest order is an open travelling-salesman path problem. :func:`optimize_order` builds a
nearest-neighbour tour, keeps the cheaper of it and the raster order, and improves it with 2-opt and
Or-opt moves (Croes 1958; Or 1976; see Johnson & McGeoch, "The traveling salesman problem: a case study
in local optimization", 1997) over exact neighbour lists with don't-look bits
(:mod:`gonio.plan.localsearch`), in about N log N time on spread poses.

Lower bound
-----------
Every visiting order is a Hamiltonian path through the poses (plus the start position, if fixed), and
a Hamiltonian path is a spanning tree, so its move time is at least the weight of the minimum spanning
tree under the same move-time metric (no triangle inequality needed, only non-negative symmetric
costs). Hence ``lower bound = N · pose_time + MST`` is a true lower bound of every order's lab time.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from gonio.plan import neighbours as _nb
from gonio.progress import progress, progress_counter
from gonio.rig.kinematics import trapezoid_time


__all__ = [
    "MotionModel",
    "LabTimeEstimate",
    "path_move_time",
    "raster_order",
    "nearest_neighbour_order",
    "optimize_order",
    "mst_move_time",
    "estimate",
]

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class MotionModel:
    """Per-joint speed and acceleration limits of a rig.

    Attributes
    ----------
    names : tuple of str
        Joint names (J of them).
    vmax : ndarray (J,)
        Maximum joint speed, rad/s.
    amax : ndarray (J,)
        Maximum joint acceleration, rad/s².
    wrap : ndarray (J,) bool
        True for continuous-rotation joints (moves take the shorter way round).
    """

    names: tuple[str, ...]
    vmax: np.ndarray
    amax: np.ndarray
    wrap: np.ndarray | None = None

    def __post_init__(self):
        j = len(self.names)
        for key in ("vmax", "amax"):
            arr = np.asarray(getattr(self, key), dtype=np.float64).reshape(-1)
            if arr.shape != (j,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
                raise ValueError(f"MotionModel.{key} = {arr.tolist()}: need {j} positive numbers")
            object.__setattr__(self, key, arr)
        wrap = np.zeros(j, bool) if self.wrap is None else np.asarray(self.wrap, dtype=bool).reshape(-1)
        if wrap.shape != (j,):
            raise ValueError(f"MotionModel.wrap has {wrap.size} entries, expected {j}")
        object.__setattr__(self, "wrap", wrap)

    @classmethod
    def from_rig(cls, rig) -> "MotionModel":
        """The speed/acceleration limits of a :class:`gonio.rig.kinematics.Rig` (no wrap joints), as the rig
        file states them: what orders poses and bounds lab time (the servos never move faster)."""
        return cls(tuple(rig.names), rig.max_speed, rig.max_accel)

    @classmethod
    def as_run(cls, rig) -> "MotionModel":
        """The limits :meth:`from_rig` states as the rig's servos run them: the driver writes each joint's
        limits as Profile Velocity/Acceleration registers, rounded down to their units
        (:meth:`gonio.rig.control_table.ControlTable.profile_limits`: the default rig's 80-90°/s² run 6-8 %
        slower, which the lab-time estimate missed); a joint whose servo model has no control table keeps
        its stated limits. Used for the moves of an estimate (:func:`gonio.plan.plan_move_times`), not for
        ordering: unequal speed/acceleration ratios make the k-d tree's bound loose (:mod:`gonio.plan.neighbours`)."""
        from gonio.errors import ConfigError
        from gonio.rig.control_table import load_control_table

        speed, accel = np.array(rig.max_speed, dtype=np.float64), np.array(rig.max_accel, dtype=np.float64)
        for k, j in enumerate(rig.joints):
            try:
                table = load_control_table(j.model)
            except ConfigError:
                continue
            speed[k], accel[k] = table.profile_limits(j.max_speed, j.max_accel, j.gear_ratio)
        return cls(tuple(rig.names), speed, accel)

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def deltas(self, a, b) -> np.ndarray:
        """|Δq| per joint between joint vectors ``a`` and ``b`` (broadcast), shorter way for wrap joints."""
        d = np.abs(np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64))
        if self.wrap.any():
            w = d[..., self.wrap] % _TWO_PI
            d[..., self.wrap] = np.minimum(w, _TWO_PI - w)
        return d

    def joint_times(self, a, b) -> np.ndarray:
        """Per-joint trapezoidal move times ``t_j(|Δq_j|)``, shape ``(..., J)``."""
        return trapezoid_time(self.deltas(a, b), self.vmax, self.amax)

    def move_time(self, a, b) -> np.ndarray:
        """Concurrent move time ``max_j t_j(|Δq_j|)`` between ``a`` and ``b`` (shape ``(..., J)``)."""
        return self.joint_times(a, b).max(axis=-1)

    def sequential_move_time(self, a, b) -> np.ndarray:
        """Move time when joints move one at a time: ``Σ_j t_j`` over the joints that move."""
        return self.joint_times(a, b).sum(axis=-1)


@dataclass(frozen=True)
class LabTimeEstimate:
    """Lab time of a plan under a motion model, seconds.

    ``optimized``: the order the plan uses; ``lower_bound``: N·pose_time + MST (no order is faster);
    ``raster``: raster order moving one axis at a time (the naive baseline); ``raster_concurrent``:
    raster order with concurrent joints.
    """

    n_poses: int
    pose_time: float
    optimized: float
    lower_bound: float
    raster: float
    raster_concurrent: float
    startup: float = 0.0  #: of ``optimized``: the session's first darks and warm-up (0: poses only)
    auto_exposure: bool = False  #: capture time estimated with the expected bracket
    account: dict | None = None  #: :meth:`gonio.plan.labtime.LabAccount.to_dict` of ``optimized``

    @property
    def ratio_to_raster(self) -> float:
        """optimized / raster baseline (< 1 is a saving)."""
        return self.optimized / self.raster if self.raster > 0 else 1.0

    @property
    def ratio_to_bound(self) -> float:
        """optimized / lower bound (≥ 1; how far from optimal at most)."""
        return self.optimized / self.lower_bound if self.lower_bound > 0 else 1.0

    def to_dict(self) -> dict[str, float]:
        return {"n_poses": self.n_poses, "pose_time": self.pose_time, "optimized": self.optimized,
                "lower_bound": self.lower_bound, "raster": self.raster,
                "raster_concurrent": self.raster_concurrent, "ratio_to_raster": self.ratio_to_raster,
                "ratio_to_bound": self.ratio_to_bound, "startup": self.startup, "auto_exposure": self.auto_exposure,
                "account": self.account}


def _check(joints, model: MotionModel) -> np.ndarray:
    q = np.asarray(joints, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != model.n_joints:
        raise ValueError(f"joints have shape {q.shape}, expected (N, {model.n_joints})")
    return q


def path_move_time(joints, order, model: MotionModel, *, start=None, sequential: bool = False) -> float:
    """Total move time visiting ``joints[order]`` in order (from ``start`` if given)."""
    q = _check(joints, model)[np.asarray(order, dtype=np.int64)]
    if start is not None:
        q = np.vstack([np.asarray(start, dtype=np.float64)[None, :], q])
    if q.shape[0] < 2:
        return 0.0
    fn = model.sequential_move_time if sequential else model.move_time
    return float(fn(q[:-1], q[1:]).sum())


def raster_order(poses) -> np.ndarray:
    """Lexicographic order of the rows of ``poses`` (first column outermost), as a raster scan does."""
    p = np.asarray(poses, dtype=np.float64)
    if p.shape[0] == 0:
        return np.zeros(0, np.int64)
    return np.lexsort(p.T[::-1]).astype(np.int64)


class _Graph:
    """Poses + a start node + a free end node; costs are concurrent move times.

    Node N is the start (a real joint vector, or a *virtual* node at zero cost from everything when the
    start is free); node N+1 is a virtual end at zero cost, so an open path is a cycle through both
    fixed nodes and 2-opt / Or-opt need no special cases at the ends.
    """

    def __init__(self, q: np.ndarray, model: MotionModel, start):
        n, j = q.shape
        self.x = np.vstack([q, np.zeros((2, j)) if start is None else
                            np.vstack([np.asarray(start, dtype=np.float64).reshape(1, j), np.zeros((1, j))])])
        self.virtual = np.zeros(n + 2, bool)
        self.virtual[n + 1] = True
        self.virtual[n] = start is None
        self.model = model

    def cost(self, a, b) -> np.ndarray:
        a = np.asarray(a)
        b = np.asarray(b)
        t = self.model.move_time(self.x[a], self.x[b])
        return np.where(self.virtual[a] | self.virtual[b], 0.0, t)


def nearest_neighbour_order(joints, model: MotionModel, *, start=None, seed: int = 0,
                            nbrs=None) -> np.ndarray:
    """Greedy nearest-neighbour order (by concurrent move time; ties: lowest index).

    Starts at the pose nearest ``start`` if given, else at a pose chosen by ``seed``. Exact nearest
    unvisited pose from k-d tree queries (:class:`gonio.plan.neighbours.NearestUnvisited`), O(N log N) on
    spread poses; the same order as :func:`_nearest_neighbour_order_dense` (O(N²), the reference).
    """
    q = _check(joints, model)
    n = q.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    if not _nb.supported(model) or n < 64:
        return _nearest_neighbour_order_dense(q, model, start=start, seed=seed)
    finder = _nb.NearestUnvisited(q, model, nbrs if nbrs is not None else _nb.knn(q, model, 10))
    order = np.empty(n, np.int64)
    if start is None:
        cur = int(np.random.default_rng(seed).integers(n))
    else:
        cur = finder.nearest_point(np.asarray(start, dtype=np.float64))
    for k in progress(range(n), total=n, desc="ordering (nearest neighbour)", unit="pose", delay=2.0):
        order[k] = cur
        finder.visit(cur)
        if k < n - 1:
            cur = finder.nearest_to(cur)
    return order


def _nearest_neighbour_order_dense(joints, model: MotionModel, *, start=None, seed: int = 0) -> np.ndarray:
    """Reference greedy nearest-neighbour order: one dense O(N) row per step, O(N²) in all."""
    q = _check(joints, model)
    n = q.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    unvisited = np.ones(n, bool)
    order = np.empty(n, np.int64)
    if start is None:
        cur = int(np.random.default_rng(seed).integers(n))
    else:
        cur = int(np.argmin(model.move_time(np.asarray(start, dtype=np.float64)[None, :], q)))
    for k in range(n):
        order[k] = cur
        unvisited[cur] = False
        if k == n - 1:
            break
        d = model.move_time(q[cur][None, :], q)
        d[~unvisited] = np.inf
        cur = int(np.argmin(d))
    return order


def _scalar_cost(g: _Graph):
    """``cost(a, b)``: the move time between graph nodes ``a`` and ``b`` in plain Python, cached (the
    local search evaluates a few costs per candidate move, so NumPy's call overhead would dominate).
    Same formula as :meth:`MotionModel.move_time`."""
    m = g.model
    x = g.x.tolist()
    virtual = g.virtual.tolist()
    joints = [(float(v), float(a), float(v * v / a), bool(w), j) for j, (v, a, w) in enumerate(zip(m.vmax, m.amax, m.wrap))]
    size = len(x)
    cache: dict[int, float] = {}
    get = cache.get
    sqrt, fmod = math.sqrt, math.fmod

    def cost(a: int, b: int) -> float:
        key = a * size + b if a < b else b * size + a
        got = get(key)
        if got is not None:
            return got
        worst = 0.0
        if not (virtual[a] or virtual[b]):
            xa, xb = x[a], x[b]
            for v, acc, knee, wrap, j in joints:
                d = abs(xa[j] - xb[j])
                if wrap:
                    d = fmod(d, _TWO_PI)
                    d = min(d, _TWO_PI - d)
                t = 2.0 * sqrt(d / acc) if d < knee else d / v + v / acc
                if t > worst:
                    worst = t
        cache[key] = worst
        return worst

    return cost


def _neighbours(q: np.ndarray, model: MotionModel, k: int, nbrs=None) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` poses nearest each pose by move time and those times, nearest first: ``(index, time)``
    each ``(N, k)`` (k-d tree, exact; dense rows when the k-d tree bound does not apply or N is small)."""
    if _nb.supported(model) and q.shape[0] > k + 1:
        idx, dist = nbrs if nbrs is not None else _nb.knn(q, model, k)
        return idx[:, :k], dist[:, :k]
    return _neighbours_dense(q, model, k)


def _neighbours_dense(q: np.ndarray, model: MotionModel, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference neighbour lists: one dense row per pose, O(N²)."""
    n = q.shape[0]
    k = min(k, n - 1)
    idx = np.zeros((n, k), np.int64)
    dist = np.zeros((n, k))
    for i in range(n):
        d = model.move_time(q[i][None, :], q)
        d[i] = np.inf
        o = np.lexsort((np.arange(n), d))[:k]
        idx[i], dist[i] = o, d[o]
    return idx, dist


def _start_neighbours(q: np.ndarray, model: MotionModel, start, k: int) -> tuple[list[int], list[float]]:
    """The ``k`` poses nearest the fixed start, nearest first (one dense row)."""
    d = model.move_time(np.asarray(start, dtype=np.float64)[None, :], q)
    o = np.lexsort((np.arange(d.size), d))[:k]
    return o.tolist(), d[o].tolist()


def optimize_order(joints, model: MotionModel, *, start=None, seed: int = 0, time_budget: float | None = None,
                   max_passes: float = 30, neighbours: int = 10,
                   initial: Sequence[int] | None = None, timings: dict | None = None) -> np.ndarray:
    """An order of the poses with small total move time.

    Builds the nearest-neighbour order, keeps it or ``initial`` (default: the raster order of the
    joint vectors) whichever moves less, then improves it with 2-opt and Or-opt moves over the
    ``neighbours`` nearest poses of each pose (:func:`gonio.plan.localsearch.improve`: don't-look bits,
    array tour reversing the shorter side) until no move improves, after ``max_passes`` visits per pose,
    or when ``time_budget`` wall seconds have elapsed (default ``None``: no wall-clock limit, so the
    order depends only on the poses and ``seed`` — a plan is data and must be reproducible on any
    machine; 10⁴ spread poses take a few seconds). The result is never slower than the raster order.
    ``timings``: if given, receives the wall seconds of each step (``tour``: neighbour lists and the
    nearest-neighbour tour; ``local search``) and their CPU seconds (``tour cpu``, ``local search cpu``).
    """
    from gonio.plan.localsearch import improve

    q = _check(joints, model)
    n = q.shape[0]
    if n <= 1:
        return np.arange(n, dtype=np.int64)
    t0, c0 = time.perf_counter(), time.process_time()
    deadline = np.inf if time_budget is None else t0 + float(time_budget)
    nbrs = _nb.knn(q, model, max(neighbours, 10)) if _nb.supported(model) and n > max(neighbours, 10) + 1 else None
    if initial is not None:
        initial = np.asarray(initial, dtype=np.int64)
        if initial.shape != (n,) or not np.array_equal(np.sort(initial), np.arange(n)):
            raise ValueError("optimize_order: initial must be a permutation of the pose indices")
    cands = [nearest_neighbour_order(q, model, start=start, seed=seed, nbrs=nbrs),
             raster_order(q) if initial is None else initial]
    costs = [path_move_time(q, c, model, start=start) for c in cands]
    best = cands[int(np.argmin(costs))]
    t1, c1 = time.perf_counter(), time.process_time()
    idx, dist = _neighbours(q, model, neighbours, nbrs)
    # the local search runs on the poses renumbered in the order of the starting tour (pose best[k] is
    # node k; the start and end nodes keep N and N+1, each list keeps its order): the same moves, since
    # only costs, list order and tour position decide them, but the poses a move touches are near each
    # other in memory (at 10⁵ poses the search ran ~1.4x slower in the poses' own numbering)
    inv, idx, dist = _renumbered(best, idx, dist)
    nbr_idx, nbr_cost = idx.tolist(), dist.tolist()
    s_idx, s_cost = ([], []) if start is None else _start_neighbours(q, model, start, neighbours)
    nbr_idx += [inv[np.asarray(s_idx, dtype=np.int64)].tolist(), []]
    nbr_cost += [s_cost, []]
    tour = np.concatenate([[n], np.arange(n), [n + 1]]).astype(np.int64)
    with progress_counter(desc="ordering (2-opt/Or-opt)", unit="visit", delay=2.0) as tick:
        tour = improve(tour, _scalar_cost(_Graph(q[best], model, start)), nbr_idx, nbr_cost, n, start is not None,
                       max_passes=max_passes, deadline=deadline, progress=tick)
    if timings is not None:
        timings.update({"tour": t1 - t0, "local search": time.perf_counter() - t1, "tour cpu": c1 - c0,
                        "local search cpu": time.process_time() - c1})
    perm = best[tour[1:-1]]
    if nbrs is not None:  # the ordered plan's estimate needs them again (its spanning tree): renumbered
        _nb.remember(q[perm], model, _renumbered(perm, *nbrs)[1:])
    return perm


def _renumbered(order: np.ndarray, idx: np.ndarray, dist: np.ndarray):
    """Neighbour lists ``(idx, dist)`` (one row per pose) of the poses taken in ``order``: row ``k`` is pose
    ``order[k]``'s, its entries renumbered to positions in ``order``. Returns ``(inv, idx, dist)``, ``inv``
    the inverse permutation (pose → position)."""
    inv = np.empty(order.size, np.int64)
    inv[order] = np.arange(order.size)
    return inv, inv[idx[order]], dist[order]


def _optimize_order_reference(joints, model: MotionModel, *, start=None, seed: int = 0, max_passes: int = 30,
                              neighbours: int = 10, initial: Sequence[int] | None = None,
                              timings: dict | None = None) -> np.ndarray:
    """:func:`optimize_order` with the previous local search
    (:func:`gonio.plan.localsearch.reference_search`, O(N²) on large sets): the reference of tests and
    ``benchmarks/bench_plan.py``."""
    from gonio.plan.localsearch import reference_search

    q = _check(joints, model)
    n = q.shape[0]
    if n <= 1:
        return np.arange(n, dtype=np.int64)
    cands = [nearest_neighbour_order(q, model, start=start, seed=seed),
             raster_order(q) if initial is None else np.asarray(initial, dtype=np.int64)]
    best = cands[int(np.argmin([path_move_time(q, c, model, start=start) for c in cands]))]
    tour = np.concatenate([[n], best, [n + 1]]).astype(np.int64)
    t0, c0 = time.perf_counter(), time.process_time()
    idx, _ = _neighbours(q, model, neighbours)
    reference_search(_scalar_cost(_Graph(q, model, start)), tour, idx.tolist(), np.inf, max_passes)
    if timings is not None:
        timings.update({"local search": time.perf_counter() - t0, "local search cpu": time.process_time() - c0})
    return tour[1:-1].copy()


def mst_move_time(joints, model: MotionModel, *, start=None) -> float:
    """Weight of the minimum spanning tree of the poses (and ``start``) under concurrent move time.

    Borůvka rounds over exact k-d tree neighbour lists (:func:`gonio.plan.neighbours.mst_weight`; the
    lists :func:`optimize_order` built when these are the poses it ordered, else new ones),
    O(N log N) on spread poses; the same weight as Prim's (:func:`_mst_move_time_dense`, the reference).
    """
    q = _check(joints, model)
    if start is not None:
        q = np.vstack([np.asarray(start, dtype=np.float64)[None, :], q])
    if not _nb.supported(model) or q.shape[0] < 64:
        return _mst_move_time_dense(q, model)
    return _nb.mst_weight(q, model, nbrs=_nb.recall(q, model))  # the lists ordering built, if these poses


def _mst_move_time_dense(joints, model: MotionModel, *, start=None) -> float:
    """Reference MST weight: Prim's algorithm with dense rows computed on the fly, O(N²·J) time, O(N)
    memory (Prim 1957)."""
    q = _check(joints, model)
    if start is not None:
        q = np.vstack([np.asarray(start, dtype=np.float64)[None, :], q])
    n = q.shape[0]
    if n < 2:
        return 0.0
    in_tree = np.zeros(n, bool)
    in_tree[0] = True
    best = model.move_time(q[0][None, :], q)
    best[0] = np.inf
    total = 0.0
    for _ in range(n - 1):
        k = int(np.argmin(best))
        total += float(best[k])
        in_tree[k] = True
        best = np.minimum(best, model.move_time(q[k][None, :], q))
        best[in_tree] = np.inf
    return total


def estimate(poses, joints, order, model: MotionModel, pose_time: float, *, start=None) -> LabTimeEstimate:
    """Lab time of visiting ``joints[order]``, its lower bound, and the raster baselines.

    ``poses`` (N, 4) define the raster order (θi outermost, as a nested-loop script scans);
    ``joints`` (N, J) the moves; ``pose_time`` the fixed settle + capture seconds per pose.
    """
    q = _check(joints, model)
    n = q.shape[0]
    fixed = n * float(pose_time)
    raster = raster_order(poses)
    return LabTimeEstimate(
        n_poses=n,
        pose_time=float(pose_time),
        optimized=fixed + path_move_time(q, order, model, start=start),
        lower_bound=fixed + mst_move_time(q, model, start=start),
        raster=fixed + path_move_time(q, raster, model, start=start, sequential=True),
        raster_concurrent=fixed + path_move_time(q, raster, model, start=start),
    )
