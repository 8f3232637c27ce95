"""Exact set-cover labels: the fewest candidate views whose scans cover every observable
reference point a state has not covered yet (SCVP's label, solved with HiGHS instead of Gurobi).

The problem at a state whose scans covered C (``nbvdata.simulation.oracle``'s packed masks): the points
R = observable - C, and for every view v the set O_v & R. A cover is a set of views whose O_v
together hold R; opt(C) is the size of the smallest. The views already scanned count as given
(their points are in C) and the overlap rule is no part of the problem, as in SCVP.

Reductions, each keeping the optimum and the canonical set below:

- Points with the same covering set (the views that see them) are one row; a point whose
  covering set contains another point's is dropped (covering the smaller set covers it too):
  the rows are the minimal covering sets (``_minimal_rows``).
- A view that covers no row, or only rows that a lower-indexed view also covers, is dropped as a
  candidate: replacing it by that view gives a cover no larger and lexicographically smaller.
- Small covers are found, or proved not to exist, by an exact branching search first
  (``_search``: cover the uncovered row seen by the fewest views, by each of its views in turn,
  never a view a sibling branch has tried): it proves in a fraction of a second what HiGHS takes
  minutes over on dense instances (a mesh whose points are each seen by hundreds of views, whose
  LP bound is far below the optimum), and gives up after ``SEARCH_NODES`` branches, where the
  MILP takes over.
- Two cheap covers bound the search from above: the greedy cover (most new points first, ties to
  the lowest index) and, along a run, the previous state's cover (``label_run_state``). SciPy's
  ``milp`` takes no starting solution, so the best of them enters as a constraint instead: the
  solver is asked only for a cover smaller than it, between the known lower bound and that.

The stored set is a function of the problem, never of the solver's path: a set from the solver
(HiGHS may pick another optimal set with other settings or versions) is replaced by the
lexicographically smallest optimal cover (``_lexicographic_cover``); a set kept from a cheap cover
is a function of the run already.

The work is bounded by a count, never by time: a state may use ``oracle.cover_node_limit``
branch-and-bound nodes in all its solver calls together (``NodeBudget``; HiGHS counts them, and
its search is deterministic). A state that uses them up keeps the best set found and the proven
bound (``Cover.proved`` tells) - the same ones on an idle machine and a busy one, whatever the
speed. The root of each solve (presolve, LP, cuts) is not counted, but it is finite and the same
work everywhere; it is what the ``benchmarks/cover.py`` time measures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from nbvdata.simulation.oracle import ViewOracle, pack_bits, popcount, unpack_bits

FEASIBILITY_TOLERANCE = 1e-6  # on LP bounds compared with integers


@dataclass(frozen=True)
class Cover:
    """A state's set-cover label.

    views : sorted indices of the chosen views (the optimal set, or the best found)
    bound : proven lower bound on the optimum (== size when proved optimal)
    greedy : size of the greedy cover
    """

    views: tuple[int, ...]
    bound: int
    greedy: int

    @property
    def size(self) -> int:
        return len(self.views)

    @property
    def proved(self) -> bool:
        return self.bound == self.size


class NodeBudget:
    """The branch-and-bound nodes a state's set cover may still use (``oracle.cover_node_limit``),
    shared by all its solver calls: each takes what HiGHS reports it used."""

    def __init__(self, nodes: int):
        self.nodes = int(nodes)

    def spend(self, used: int | None) -> None:
        self.nodes = max(self.nodes - int(used or 0), 0)

    @property
    def spent(self) -> bool:
        return self.nodes <= 0


def greedy_cover(oracle: ViewOracle, covered: np.ndarray) -> list[int]:
    """The greedy cover of the points ``oracle.observable - covered`` ((W,) packed): the view that
    covers the most of them next, ties to the lowest index, until none is left."""
    covered = covered | ~oracle.observable
    chosen = []
    while popcount(~covered) > 0:
        view = int(np.argmax(oracle.score(covered).new))
        chosen.append(view)
        covered = covered | oracle.visible[view]
    return chosen


@numba.njit(cache=True)
def _subset(packed, a, b):
    """Whether row ``a`` of ``packed`` ((n, W) uint64 bit sets) is a subset of row ``b``."""
    for w in range(packed.shape[1]):
        if packed[a, w] & ~packed[b, w]:
            return False
    return True


@numba.njit(cache=True)
def _minimal(signatures, order):
    """keep[i]: no row kept before row i (in ``order``, which sorts the (U, W) uint64 rows by size,
    so a row's subsets come before it) is a subset of it: the minimal rows, one of each set."""
    count = signatures.shape[0]
    keep = np.zeros(count, dtype=np.bool_)
    kept = np.empty(count, dtype=np.int64)
    found = 0
    for position in range(count):
        row = order[position]
        dominated = False
        for k in range(found):
            if _subset(signatures, kept[k], row):
                dominated = True
                break
        if not dominated:
            keep[row] = True
            kept[found] = row
            found += 1
    return keep


def _minimal_rows(oracle: ViewOracle, remaining: np.ndarray) -> np.ndarray:
    """(n, V) bool: the distinct minimal covering sets of the points in ``remaining`` ((W,) packed),
    one row each, in the order of their first point (a set equal to an earlier one is dropped as
    its superset)."""
    signatures = oracle.point_views[unpack_bits(remaining, oracle.points)]  # (R, ceil(V / 64))
    sizes = np.bitwise_count(signatures).sum(axis=1, dtype=np.int64)
    keep = _minimal(signatures, np.argsort(sizes, kind="stable"))
    return unpack_bits(signatures[keep], len(oracle.visible))


@numba.njit(cache=True)
def _dominated_by_lower(columns):
    """dominated[j]: some view i < j covers every row view j covers (``columns``: (V, W) uint64,
    each view's rows packed)."""
    views = columns.shape[0]
    dominated = np.zeros(views, dtype=np.bool_)
    for j in range(views):
        for i in range(j):
            if _subset(columns, j, i):
                dominated[j] = True
                break
    return dominated


def _candidates(rows: np.ndarray) -> np.ndarray:
    """(V,) bool: views that cover a row and whose rows no lower-indexed view's rows contain."""
    return rows.any(axis=0) & ~_dominated_by_lower(pack_bits(rows.T))


def _covers(rows: np.ndarray, views) -> bool:
    return bool(rows[:, sorted(views)].any(axis=1).all()) if len(rows) else True


SEARCH_NODES = 500_000  # branches of one exact search before the MILP takes over (a count: the same everywhere)


@numba.njit(cache=True)
def _first_row(words):
    """Index of the lowest set bit of (W,) uint64 ``words``, -1 for none."""
    for w in range(words.shape[0]):
        x = words[w]
        if x:
            b = 0
            while not (x >> np.uint64(b)) & np.uint64(1):
                b += 1
            return w * 64 + b
    return -1


@numba.njit(cache=True)
def _search(columns, covering, starts, k, budget):
    """A cover of every row by at most ``k`` views, by exact branching: the first uncovered row
    (rows are numbered fewest views first) is covered by each of its views in turn, and a view a
    sibling branch has tried stays out of the later siblings' subtrees (any cover holding it was
    searched there).

    columns (V, W) uint64: view v's rows; covering[starts[r]:starts[r + 1]]: the views that cover
    row r, ascending. Returns (size or -1 for none, (k,) chosen views, branches used, finished):
    finished False when ``budget`` branches did not decide it."""
    views, words = columns.shape
    rows = starts.shape[0] - 1
    chosen = np.full(max(k, 1), -1, dtype=np.int64)
    if rows == 0:
        return 0, chosen, 0, True
    if k == 0:
        return -1, chosen, 0, True
    uncovered = np.zeros((k + 1, words), dtype=np.uint64)
    for r in range(rows):
        uncovered[0, r // 64] |= np.uint64(1) << np.uint64(r % 64)
    excluded = np.zeros((k + 1, views), dtype=np.bool_)
    row = np.empty(k + 1, dtype=np.int64)
    at = np.empty(k + 1, dtype=np.int64)
    row[0], at[0] = 0, starts[0]
    depth, used = 0, 0
    while True:
        if at[depth] == starts[row[depth] + 1]:  # every view of this row tried: back up
            depth -= 1
            if depth < 0:
                return -1, chosen, used, True
            excluded[depth, chosen[depth]] = True
            at[depth] += 1
            continue
        v = covering[at[depth]]
        if excluded[depth, v]:
            at[depth] += 1
            continue
        used += 1
        if used > budget:
            return -1, chosen, used, False
        chosen[depth] = v
        left = False
        for w in range(words):
            x = uncovered[depth, w] & ~columns[v, w]
            uncovered[depth + 1, w] = x
            left = left or x != 0
        if not left:
            return depth + 1, chosen, used, True
        if depth + 1 == k:
            excluded[depth, v] = True
            at[depth] += 1
            continue
        excluded[depth + 1, :] = excluded[depth, :]
        excluded[depth + 1, v] = True
        depth += 1
        row[depth] = _first_row(uncovered[depth])
        at[depth] = starts[row[depth]]


def _smallest(rows: np.ndarray, columns: np.ndarray, lower: int, upper: int, budget: NodeBudget):
    """Smallest cover of ``rows`` ((n, V) bool) by the views ``columns`` with lower <= size <= upper:
    (views or None, proven lower bound, finished), as ``_milp_direct``. The exact search first, size
    by size from ``lower``; where it gives up, HiGHS (``_milp``) from the size it reached."""
    sub = rows[:, columns]
    order = np.argsort(sub.sum(axis=1), kind="stable")
    sub = sub[order]
    packed = pack_bits(sub.T)
    starts = np.concatenate([[0], np.cumsum(sub.sum(axis=1))]).astype(np.int64)
    covering = np.nonzero(sub)[1].astype(np.int64)
    for k in range(max(lower, 0), upper + 1):
        size, chosen, _, finished = _search(packed, covering, starts, k, SEARCH_NODES)
        if not finished:
            return _milp(rows, columns, k, upper, budget)
        if size >= 0:
            return [int(v) for v in columns[chosen[:size]]], size, True
    return None, upper + 1, True


def _milp(rows: np.ndarray, columns: np.ndarray, lower: int, upper: int, budget: NodeBudget):
    """``_milp_direct`` on a growing subset of the rows (constraint generation): a subset's program
    is a relaxation, so its optimum is a lower bound and its infeasibility is the whole program's;
    a subset's optimal cover that covers every row is optimal for all of them. Dense instances
    (thousands of rows, each seen by hundreds of views) thus solve on a few hundred rows."""
    sizes = rows.sum(axis=1)
    active = _seed_rows(rows, sizes)
    while True:
        views, bound, finished = _milp_direct(rows[active], columns, lower, upper, budget)
        if views is None or not finished:
            covers = views is not None and _covers(rows, views)
            return (views if covers else None), bound, finished
        missing = np.flatnonzero(~rows[:, views].any(axis=1))
        if not len(missing):
            return views, bound, True
        lower = max(lower, bound)  # the subset's optimum bounds the whole program's
        active = np.union1d(active, missing[np.argsort(sizes[missing], kind="stable")[:ROWS_ADDED]])


ROWS_SEED, ROWS_ADDED = 256, 128  # rows of the first subset, rows added per round


def _seed_rows(rows: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """The first subset of rows: the ``ROWS_SEED`` rows seen by the fewest views (the binding ones),
    and a greedy packing (rows no view sees two of, fewest views first): sorted indices."""
    order = np.argsort(sizes, kind="stable")
    packed, used = [], np.zeros(rows.shape[1], dtype=bool)
    for row in order:
        if not (rows[row] & used).any():
            packed.append(row)
            used |= rows[row]
    return np.union1d(order[:ROWS_SEED], np.array(packed, dtype=np.int64))


def _milp_direct(rows: np.ndarray, columns: np.ndarray, lower: int, upper: int, budget: NodeBudget):
    """Smallest cover of ``rows`` by the views ``columns`` with lower <= size <= upper.

    Returns (views or None, bound, finished): the cover found (None: none), the proven lower bound
    on the smallest cover within the size range, and whether the solver finished (proved the
    cover optimal, or that none exists) within the nodes ``budget`` has left (it takes those used)."""
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import csr_matrix

    if upper < lower or len(columns) == 0:
        return None, upper + 1, True
    if budget.spent:
        return None, lower, False
    count = len(columns)
    constraints = [LinearConstraint(csr_matrix(rows[:, columns].astype(np.float64)), lb=1, ub=np.inf),
                   LinearConstraint(np.ones((1, count)), lb=lower, ub=upper)]
    result = milp(np.ones(count), integrality=np.ones(count), bounds=Bounds(0, 1), constraints=constraints,
                  options={"node_limit": budget.nodes, "mip_rel_gap": 0.0, "disp": False})
    budget.spend(getattr(result, "mip_node_count", None) or 1)  # a solve at the root counts one
    if result.status == 2:  # infeasible: no cover within the range
        return None, upper + 1, True
    views = None if result.x is None else [int(v) for v in columns[result.x > 0.5]]
    if views is not None and not _covers(rows, views):
        views = None  # never trust a rounded solution unchecked
    bound = getattr(result, "mip_dual_bound", None)
    bound = lower if bound is None or not np.isfinite(bound) else max(lower, math.ceil(bound - FEASIBILITY_TOLERANCE))
    finished = result.status == 0 and views is not None
    return views, (len(views) if finished else bound), finished


def _lp_bound(rows: np.ndarray, columns: np.ndarray) -> tuple[float, np.ndarray] | None:
    """A lower bound on covering ``rows`` by ``columns`` and (n,) row prices that prove it (a
    feasible dual: no column's rows cost more than 1): the LP relaxation of the ``_seed_rows``
    subset, a relaxation of the whole; None when HiGHS does not solve it."""
    subset = _seed_rows(rows, rows.sum(axis=1))
    solved = _lp_direct(rows[subset], columns)
    if solved is None:
        return None
    prices = np.zeros(len(rows))
    prices[subset] = solved[1]
    return solved[0], prices


def _lp_direct(rows: np.ndarray, columns: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The LP relaxation's optimum of covering ``rows`` by ``columns`` and its dual (n,) row prices,
    or None when HiGHS does not solve it (a covering LP of a few hundred rows solves in milliseconds:
    no limit)."""
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix

    result = linprog(np.ones(len(columns)), A_ub=-csr_matrix(rows[:, columns].astype(np.float64)),
                     b_ub=-np.ones(len(rows)), bounds=(0, None), method="highs")
    if result.status == 2:  # infeasible: some row no column covers
        return math.inf, np.zeros(len(rows))
    if result.status != 0:
        return None
    return float(result.fun), np.maximum(-result.ineqlin.marginals, 0.0)


def _lexicographic_cover(rows: np.ndarray, candidates: np.ndarray, size: int, cover: list[int],
                         budget: NodeBudget) -> list[int] | None:
    """The lexicographically smallest cover of ``rows`` with ``size`` views (the optimum), given
    one such ``cover``; None when ``budget`` runs out first.

    Decides the candidate views in index order: view j joins when some optimal cover holds the
    views chosen so far and j and otherwise only views after j. A witness answers yes without a
    solve (the current cover holds j, or j swapped for one of its later views still covers);
    a lower bound answers no: a row no later view covers, the prices of the last LP relaxation
    (a feasible dual stays feasible for fewer rows and views), a fresh LP; only the rest take a
    MILP. ``candidates`` may leave out views dominated by lower-indexed ones (they are in no
    lexicographically smallest optimal cover)."""
    count = len(rows)
    matrix = rows.astype(np.float64)
    best, chosen = set(cover), []
    left = np.ones(count, dtype=bool)
    prices = np.zeros(count)
    for j in np.flatnonzero(candidates):
        j = int(j)
        if len(chosen) == size:
            break
        if not rows[left, j].any():
            continue
        if j not in best:
            if budget.spent:
                return None
            room = size - len(chosen) - 1  # views left for the rest after j
            rest = left & ~rows[:, j]
            swapped = next((best - {s} | {j} for s in sorted(best - set(chosen), reverse=True)
                            if s > j and _covers(rows, best - {s} | {j})), None)
            if swapped is not None:
                best = swapped
            else:
                later = candidates.copy()
                later[:j + 1] = False
                later_rows = matrix[np.ix_(rest, later)]
                if not later_rows.any(axis=1).all():
                    continue
                load = float((prices[rest] @ later_rows).max()) if later_rows.shape[1] else 0.0
                if prices[rest].sum() / max(load, 1.0) > room + FEASIBILITY_TOLERANCE:
                    continue
                columns = np.flatnonzero(later)
                solved = _lp_bound(rows[rest], columns)
                if solved is None:
                    return None
                relaxed, dual = solved
                prices = np.zeros(count)
                prices[rest] = dual
                if relaxed > room + FEASIBILITY_TOLERANCE:
                    continue
                views, _, finished = _smallest(rows[rest], columns, 0, room, budget)
                if not finished:
                    return None
                if views is None:
                    continue
                best = set(chosen) | {j} | set(views)
        chosen.append(j)
        left &= ~rows[:, j]
    return sorted(chosen) if not left.any() and len(chosen) == size else None


def solve_cover(oracle: ViewOracle, covered: np.ndarray, node_limit: int, incumbent: tuple[int, ...] = (),
                lower: int = 0, canonical: bool = True) -> Cover:
    """The set-cover label of the state whose covered points are ``covered`` ((W,) packed).

    ``incumbent``: views known to cover what is left (a previous state's cover), or nothing;
    ``lower``: a proven lower bound on the optimum. Uses at most ``node_limit`` branch-and-bound
    nodes (``NodeBudget``). ``canonical`` False keeps the solver's optimal set instead of the
    lexicographically smallest (the same size and bound, a fraction of the time: an evaluation's
    floor, a plan; HiGHS's set is deterministic for one HiGHS, not across its versions)."""
    budget = NodeBudget(node_limit)
    remaining = oracle.observable & ~covered
    if popcount(remaining) == 0:
        return Cover((), 0, 0)
    greedy = greedy_cover(oracle, covered)
    useful = [v for v in incumbent if popcount(oracle.visible[v] & remaining)]
    kept = useful if useful and popcount(remaining & ~np.bitwise_or.reduce(oracle.visible[useful], axis=0)) == 0 else None
    best = kept if kept is not None and len(kept) <= len(greedy) else greedy
    lower = max(lower, 1)
    if len(best) <= lower:  # a cheap cover meets the bound: optimal, and a function of the run
        return Cover(tuple(sorted(best)), len(best), len(greedy))
    rows = _minimal_rows(oracle, remaining)
    candidates = _candidates(rows)
    views, bound, finished = _smallest(rows, np.flatnonzero(candidates), lower, len(best) - 1, budget)
    if views is None:  # none smaller: the cheap cover is optimal if the solver finished
        return Cover(tuple(sorted(best)), len(best) if finished else min(bound, len(best)), len(greedy))
    if finished and canonical:
        smallest = _lexicographic_cover(rows, candidates, len(views), views, budget)
        views = smallest if smallest is not None else views
    return Cover(tuple(sorted(views)), min(bound, len(views)), len(greedy))


def next_cover(oracle: ViewOracle, covered: np.ndarray, previous: Cover, moved_to: int | None,
               node_limit: int) -> Cover:
    """The label of the state a run reaches from the state labelled ``previous`` by scanning
    candidate view ``moved_to`` (None: a scan that is no candidate's noise-free scan).

    Two facts about covers spare most solves. Let R be the points the previous state had left
    and R' those left now (R' is R less what the scan covered, a subset of R):

    1. Every cover of R covers R' (R' is a subset of R): ``previous`` still covers, so
       opt(R') <= |previous|.
    2. When the scan covered exactly O_a of candidate view a: for any cover T of R', T + {a}
       covers R (R - R' lies in O_a), so opt(R) <= opt(R') + 1, i.e.
       opt(R') >= opt(R) - 1 >= previous.bound - 1.

    So when a is in an optimal ``previous``, previous - {a} covers R' (points only a covered are
    gone) with opt(R) - 1 views, the lower bound: it is optimal and no solve is needed. The same
    holds for a run's first state with ``previous`` the cover of the mesh with no view scanned
    (``Scene.empty_cover``): opt(start) is that optimum or one less.
    """
    incumbent = tuple(v for v in previous.views if v != moved_to)
    lower = previous.bound - 1 if moved_to is not None else 0
    return solve_cover(oracle, covered, node_limit, incumbent, lower)
