"""Joint Compatibility Branch and Bound (Neira and Tardos 2001).

The search goes through the scan's measurements in order; each is paired with one of its
individually compatible landmarks not yet used, or with none. A hypothesis (a partial
pairing) is kept only while it is jointly compatible: the joint Mahalanobis distance
squared of all its pairs, with the correlations between them, below the chi-square
quantile of 2p dof. The answer is the hypothesis with the most pairs, ties broken by
the smaller joint distance.

The joint distance grows incrementally: with the hypothesis's joint innovation
covariance S = L L^T and w = L^-1 nu, adding a pair appends B = (L^-1 S_cross^T)^T and
L_22 = chol(S_new - B B^T), w_2 = L_22^-1 (nu_new - B w); the distance grows by |w_2|^2.
So it never shrinks, which is what the bound uses: a branch is cut when even pairing
every remaining measurement could not beat the best hypothesis found (more pairs, or
as many and a smaller distance).

Bounded in time by construction, whatever the scan: the search keeps the inverse of L
(not L), so that a hypothesis of p pairs costs O(p^2) (a product with L^-1, where a
general solve would cost O(p^3)); a scan's search stops after ``budget`` hypotheses or
``work_budget`` units of work (a hypothesis of p pairs counts (2p + 2)^2), and a scan
with over ``MAX_JOINT`` measurements in some gate is not searched at all. When the
search stops early (``exhausted``) the scan *falls back*: to the best jointly compatible
pairing found so far when the search completed one (the first is the greedy,
nearest-first one), else to nearest neighbour (``fallback`` says which). Measurements
compatible with no landmark never enter the search, and the candidates of each are tried
nearest first, so the first hypotheses reached are the greedy ones and the budget is
spent improving on them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.association.nn import nearest_neighbour
from ekfviz.association.params import DEFAULT_BUDGET, DEFAULT_WORK_BUDGET
from ekfviz.core.stats import chi2_quantile
from ekfviz.core.types import BoolArray, FloatArray, IntArray

try:  # optional, built with the filter's kernel: without it the search runs in Python
    import ekfviz.association._search as _search
except ImportError:  # pragma: no cover - no C compiler at install time
    _search = None  # type: ignore[assignment]

HAVE_SEARCH = _search is not None

# Measurements in some gate beyond which a scan is paired by nearest neighbour without a
# search: the search recurses once per measurement, and its greedy first descent alone
# would cost (2m)^3 / 6 units of work.
MAX_JOINT = 200

FALLBACK_BEST = "best found"  # the budget ran out: the best complete pairing found so far
FALLBACK_NN = "nearest neighbour"  # ... before any was complete, or too many measurements

_QUANTILES: dict[tuple[float, int], float] = {}


def joint_threshold(probability: float, dof: int) -> float:
    """The chi-square quantile of ``dof`` degrees of freedom at ``probability`` (cached)."""
    key = (probability, dof)
    value = _QUANTILES.get(key)
    if value is None:
        value = _QUANTILES[key] = chi2_quantile(probability, dof)
    return value


@dataclass(frozen=True, slots=True)
class JcbbResult:
    """:param pairing: (m,) the candidate column of each measurement, -1 where none
    :param hypotheses: hypotheses (search nodes) explored
    :param joint_d2: joint Mahalanobis distance squared of the pairing
    :param exhausted: the budget ran out before the search was complete (or the scan had
        over ``MAX_JOINT`` measurements to search)
    :param fallback: what the pairing is then: ``FALLBACK_BEST`` or ``FALLBACK_NN``; ""
        when the search was complete
    :param work: units of work spent (see ``DEFAULT_WORK_BUDGET``)"""

    pairing: IntArray
    hypotheses: int
    joint_d2: float
    exhausted: bool
    fallback: str = ""
    work: int = 0


def jcbb(
    nu: FloatArray,
    d2: FloatArray,
    compatible: BoolArray,
    C: FloatArray,
    R: FloatArray,
    probability: float,
    budget: int = DEFAULT_BUDGET,
    work_budget: int = DEFAULT_WORK_BUDGET,
    *,
    compiled: bool = True,
) -> JcbbResult:
    """The largest jointly compatible pairing of one scan, or a fallback (see the module).

    :param nu: (m, K, 2) innovation of each measurement against each candidate landmark
    :param d2: (m, K) their individual Mahalanobis distances squared (to order the search)
    :param compatible: (m, K) individual compatibility
    :param C: (2K, 2K) H P H^T of the candidates stacked (their joint covariance of
        predicted measurements, without R)
    :param R: (2, 2) measurement noise, added once per pair
    :param probability: of the joint gate
    :param budget: hypotheses per scan
    :param work_budget: units of work per scan
    :param compiled: search in ``_search.c`` where it was built (the same nodes, see
        there), else in Python
    """
    if _search is not None and compiled:
        return _compiled_jcbb(nu, d2, compatible, C, R, probability, budget, work_budget)
    order: list[int] = np.flatnonzero(compatible.any(axis=1)).tolist()
    if len(order) > MAX_JOINT:
        return JcbbResult(
            nearest_neighbour(d2, compatible), 0, 0.0, exhausted=True, fallback=FALLBACK_NN
        )
    found = _Search(nu, d2, compatible, C, R, order, probability, budget, work_budget)
    found.search(0, np.zeros((0, 0)), np.zeros(0), 0.0)
    return _result(d2, compatible, found.best, found.best_d2, found.nodes, found.work,
                   found.exhausted, found.complete)  # fmt: skip


class _Search:
    """The branch and bound of :func:`jcbb` in Python: what it searches (the
    measurements in some gate, their candidates nearest first, each candidate's own block
    of C plus R, as floats) and where it stands (the best hypothesis, the nodes and work
    spent, the hypothesis being grown)."""

    def __init__(
        self,
        nu: FloatArray,
        d2: FloatArray,
        compatible: BoolArray,
        C: FloatArray,
        R: FloatArray,
        order: list[int],
        probability: float,
        budget: int,
        work_budget: int,
    ) -> None:
        # each measurement's compatible candidates, nearest first (ties in column order):
        # a stable sort of the rows with the incompatible as NaN, which sorts after any number
        nearest = np.argsort(np.where(compatible, d2, np.nan), axis=1, kind="stable")
        counts = np.count_nonzero(compatible, axis=1).tolist()
        self.order = order
        self.candidates = [nearest[i, : counts[i]].tolist() for i in order]
        self.depth_total = len(order)
        self.C, self.probability = C, probability
        self.budget, self.work_budget = budget, work_budget
        r00, r01, r11 = float(R[0, 0]), float(R[0, 1]), float(R[1, 1])
        # per candidate k, its own block of C plus R, and each measurement's innovations,
        # as floats: a hypothesis's work is then float arithmetic but for the products
        # with L^-1
        diagonal, above = np.diagonal(C), np.diagonal(C, 1)
        self.own = list(
            zip(
                (diagonal[0::2] + r00).tolist(),
                (above[0::2] + r01).tolist(),
                (diagonal[1::2] + r11).tolist(),
                strict=True,
            )
        )
        self.nu_of = nu[order].tolist()  # nu_of[depth][k] = [bearing, range]
        self.thresholds: dict[int, float] = {}
        self.best_pairs = 0
        self.best_d2 = 0.0
        self.best: list[tuple[int, int]] = []
        self.complete = False  # a whole hypothesis (every measurement decided) was reached
        self.nodes = 0
        self.work = 0
        self.exhausted = False
        self.chosen: list[tuple[int, int]] = []
        self.used: set[int] = set()

    def search(self, depth: int, L_inv: FloatArray, w: FloatArray, dist2: float) -> None:
        """One level: L_inv is the inverse of the hypothesis's Cholesky factor L."""
        pairs = len(self.chosen)
        if depth == self.depth_total:
            self.complete = True
            if pairs > self.best_pairs or (
                pairs == self.best_pairs and pairs and dist2 < self.best_d2
            ):
                self.best_pairs, self.best_d2, self.best = pairs, dist2, list(self.chosen)
            return
        reachable = pairs + self.depth_total - depth
        if reachable < self.best_pairs or (
            reachable == self.best_pairs and self.best_pairs and dist2 >= self.best_d2
        ):
            return  # the bound: no completion of this branch can beat the best
        i = self.order[depth]
        nu_i = self.nu_of[depth]
        cost = (2 * pairs + 2) ** 2
        threshold = self._threshold(pairs)
        M: FloatArray | None = None  # L^-1 times the rows of the chosen pairs in C, once
        for k in self.candidates[depth]:
            if k in self.used:
                continue
            if self.nodes >= self.budget or self.work + cost > self.work_budget:
                self.exhausted = True
                return
            self.nodes += 1
            self.work += cost
            a00, a01, a11 = self.own[k]
            nu0, nu1 = nu_i[k]
            if pairs:
                if M is None:
                    cols = [2 * kk + t for _, kk in self.chosen for t in (0, 1)]
                    M = L_inv @ self.C[cols]  # (2p, 2K): column 2k + t is L^-1 S_cross^T's
                    squares = np.einsum("ij,ij->j", M, M).tolist()
                    crosses = np.einsum("ij,ij->j", M[:, 0::2], M[:, 1::2]).tolist()
                    shifts = (w @ M).tolist()
                # S_new - B B^T and nu_new - B w, B = (L^-1 S_cross^T)^T (2 x 2p)
                a00 -= squares[2 * k]
                a01 -= crosses[k]
                a11 -= squares[2 * k + 1]
                nu0 -= shifts[2 * k]
                nu1 -= shifts[2 * k + 1]
            grown = _grown((a00, a01, a11), (nu0, nu1), dist2, threshold)
            if grown is None:
                continue
            L22_inv, w_new, grown_d2 = grown
            self.chosen.append((i, k))
            self.used.add(k)
            B = None if M is None else M[:, 2 * k : 2 * k + 2]
            self.search(depth + 1, _inverse_grown(L_inv, B, L22_inv),
                        np.concatenate([w, w_new]), grown_d2)  # fmt: skip
            self.chosen.pop()
            self.used.discard(k)
            if self.exhausted:
                return
        if self.nodes >= self.budget:  # a hypothesis too: every call counts, so bounded
            self.exhausted = True
            return
        self.nodes += 1
        self.search(depth + 1, L_inv, w, dist2)  # this measurement paired with nothing

    def _threshold(self, pairs: int) -> float:
        """The joint gate of a hypothesis of ``pairs`` + 1 pairs."""
        threshold = self.thresholds.get(pairs)
        if threshold is None:
            threshold = self.thresholds[pairs] = joint_threshold(self.probability, 2 * (pairs + 1))
        return threshold


def _grown(
    schur: tuple[float, float, float],
    nu_new: tuple[float, float],
    dist2: float,
    threshold: float,
) -> tuple[FloatArray, tuple[float, float], float] | None:
    """A pair added to a hypothesis, from the 2x2 Schur complement S_new - B B^T (its
    entries a00, a01, a11) and nu_new - B w: L22^-1, w_2 = L22^-1 (nu_new - B w) and the
    joint distance grown by |w_2|^2; None where the complement is not positive definite
    or the distance leaves the gate. The 2x2 Cholesky is done in floats."""
    a00, a01, a11 = schur
    if not a00 > 0.0:
        return None
    l00 = math.sqrt(a00)
    l10 = a01 / l00
    d11 = a11 - l10 * l10
    if not d11 > 0.0:
        return None
    l11 = math.sqrt(d11)
    w0 = nu_new[0] / l00
    w1 = (nu_new[1] - l10 * w0) / l11
    grown = dist2 + w0 * w0 + w1 * w1
    if not grown < threshold:
        return None
    L22_inv = np.array(((1.0 / l00, 0.0), (-l10 / (l00 * l11), 1.0 / l11)))
    return L22_inv, (w0, w1), grown


def _inverse_grown(L_inv: FloatArray, B: FloatArray | None, L22_inv: FloatArray) -> FloatArray:
    """The inverse of the grown factor: [[L, 0], [B, L22]]^-1 = [[L^-1, 0],
    [-L22^-1 B L^-1, L22^-1]], with ``B`` given as L^-1 S_cross^T's two columns (None
    for the first pair)."""
    size = L_inv.shape[0]
    inv_new = np.zeros((size + 2, size + 2))
    if B is not None:
        inv_new[:size, :size] = L_inv
        inv_new[size:, :size] = -(L22_inv @ B.T) @ L_inv
    inv_new[size:, size:] = L22_inv
    return inv_new


def _result(
    d2: FloatArray,
    compatible: BoolArray,
    best: list[tuple[int, int]],
    best_d2: float,
    nodes: int,
    work: int,
    exhausted: bool,
    complete: bool,
) -> JcbbResult:
    """What a search found, either search's: its best pairing of (measurement,
    candidate), or nearest neighbour where its budget ran out before any hypothesis was
    complete."""
    if exhausted and not complete:
        return JcbbResult(
            nearest_neighbour(d2, compatible), nodes, 0.0, True, fallback=FALLBACK_NN, work=work
        )
    pairing = np.full(d2.shape[0], -1, dtype=np.int64)
    for i, k in best:
        pairing[i] = k
    return JcbbResult(
        pairing=pairing,
        hypotheses=nodes,
        joint_d2=best_d2,
        exhausted=exhausted,
        fallback=FALLBACK_BEST if exhausted else "",
        work=work,
    )


def _compiled_jcbb(
    nu: FloatArray,
    d2: FloatArray,
    compatible: BoolArray,
    C: FloatArray,
    R: FloatArray,
    probability: float,
    budget: int,
    work_budget: int,
) -> JcbbResult:
    """:func:`jcbb` in ``_search.c``, its preparation included (the measurements in some
    gate, their candidates nearest first, the candidates' own blocks): the same search,
    node for node, from the same arguments, without the few dozen numpy calls per scan of
    preparing it here."""
    assert _search is not None
    m, k = d2.shape
    found = _search.jcbb(
        np.ascontiguousarray(nu, dtype=np.float64),
        np.ascontiguousarray(d2, dtype=np.float64),
        np.ascontiguousarray(compatible, dtype=bool),
        np.ascontiguousarray(C, dtype=np.float64),
        np.array((R[0, 0], R[0, 1], R[1, 1]), dtype=np.float64),
        _thresholds(probability, min(m, MAX_JOINT)),
        m, k, budget, work_budget, MAX_JOINT,
    )  # fmt: skip
    if found is None:  # over MAX_JOINT measurements in some gate
        return JcbbResult(
            nearest_neighbour(d2, compatible), 0, 0.0, exhausted=True, fallback=FALLBACK_NN
        )
    pairing, best_d2, nodes, work, exhausted, complete = found
    if exhausted and not complete:
        return JcbbResult(
            nearest_neighbour(d2, compatible), nodes, 0.0, True, fallback=FALLBACK_NN, work=work
        )
    return JcbbResult(
        pairing=np.array(pairing, dtype=np.int64),
        hypotheses=nodes,
        joint_d2=best_d2,
        exhausted=bool(exhausted),
        fallback=FALLBACK_BEST if exhausted else "",
        work=work,
    )


_THRESHOLDS: dict[float, FloatArray] = {}


def _thresholds(probability: float, depth: int) -> FloatArray:
    """The joint gates of 1 to ``depth`` + 1 pairs (at least), kept per probability."""
    kept = _THRESHOLDS.get(probability)
    if kept is None or kept.shape[0] <= depth:
        grown = max(16, 0 if kept is None else 2 * kept.shape[0])
        size = max(depth + 1, min(grown, MAX_JOINT + 1))
        kept = _THRESHOLDS[probability] = np.array(
            [joint_threshold(probability, 2 * (pairs + 1)) for pairs in range(size)]
        )
    return kept
