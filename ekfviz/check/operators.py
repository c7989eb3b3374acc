"""The mutation operators of ``check``: what a mutation is, how one is applied to an
operation of :class:`~ekfviz.check.rerun.Rerun`, and the mutations generated from a matrix
operation's formula (a sign flipped of each column's, row's and single term's; each
symbolic term, and column, missing; the transpose; rows and columns swapped; cos and sin
swapped). The catalogue that applies them is :mod:`ekfviz.check.mutations`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ekfviz.check.operations import OPERATION
from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle

if TYPE_CHECKING:
    from ekfviz.check.rerun import Rerun

Apply = Callable[["Rerun", Callable[..., Any], tuple[Any, ...]], Any]

FAMILIES: dict[str, str] = {
    "sign": "a sign flipped (a term, a row or a column)",
    "transpose": "a matrix transposed, or rows or columns swapped",
    "product": "an elementwise product where a matrix product belongs, or S**-1 for S^-1",
    "missing": "a term or factor missing",
    "swapped": "arguments or components in the wrong order",
    "degrees": "degrees where radians belong",
    "index": "an index off by one, or a line read in the wrong layout",
    "stale": "a stale operand (before or after the update, the state before the line)",
    "variance": "sigmas where variances belong, or variances squared",
    "wrap": "a wrong wrap range, or no wrap",
    "skipped": "the whole operation skipped",
    "own": "a quantity of the filter's own (its noise, a constant covariance)",
    "scale": "a noise matrix used scaled (k R, k Q, k not 1), k read off the filter's result",
    "handout": "the handout's own simplification",
    "form": "another form of the update (joint or sequential): not a mistake",
}


@dataclass(frozen=True, slots=True)
class Mutation:
    """One operation computed the mistaken way.

    :param wrong: what the code does, a sentence
    :param fix: how to fix it
    :param tokens: text that marks the line computing it in a student's source
    :param when: the events it can act on (``still``: a control of d = alpha = 0,
        ``not_driving``: d = 0); empty: all of its operation's
    :param says: what the code does given the factor the search read off the filter
        (a mutation of the ``scale`` family; ``wrong`` says it with k)
    """

    operation: str
    name: str
    family: str
    wrong: str
    fix: str
    apply: Apply = field(compare=False, repr=False)
    tokens: tuple[str, ...] = ()
    when: str = ""
    says: Callable[[float], str] | None = field(default=None, compare=False, repr=False)

    @property
    def id(self) -> str:
        return f"{self.operation}.{self.name}"

    @property
    def event(self) -> str:
        return OPERATION[self.operation].event

    @property
    def mistake(self) -> bool:
        """Whether it is a mistake to fix: not the handout's simplification, nor a form."""
        return self.family not in ("handout", "form")


# -- appliers --------------------------------------------------------------------------------


def result(transform: Callable[[Any], Any]) -> Apply:
    """The operation's value, transformed."""
    return lambda rerun, function, operands: transform(np.array(function(*operands)))


def operands(transform: Callable[..., tuple[Any, ...]]) -> Apply:
    """The operation of transformed operands."""
    return lambda rerun, function, operands: function(*transform(*operands))


def in_context(transform: Callable[..., Any]) -> Apply:
    """A value made from the re-run's context (a stale operand, a fitted quantity)."""
    return lambda rerun, function, operands: transform(rerun, function, *operands)


def flipped(mask: FloatArray) -> Callable[[FloatArray], FloatArray]:
    signs = 1.0 - 2.0 * mask
    return lambda value: value * signs


def zeroed(mask: FloatArray) -> Callable[[FloatArray], FloatArray]:
    keep = 1.0 - mask
    return lambda value: value * keep


def turned(pose: FloatArray, quarter: float) -> FloatArray:
    """The pose with its heading theta replaced by ``quarter - theta``: cos and sin of the
    heading swap places (cos(pi/2 - a) = sin(a))."""
    turned = np.array(pose, dtype=np.float64)
    turned[2] = quarter - turned[2]
    return turned


# -- the matrix operations: mutations generated from their formulas --------------------------


@dataclass(frozen=True, slots=True)
class MatrixFormula:
    """A matrix-valued operation written out: its rows' and columns' names and entries.

    An entry is a term unless it is 0 or the identity's 1; a term with no symbol in it is
    a constant (H's -1).

    :param swap_trig: its operands with cos and sin of the angle swapped, or None
    """

    operation: str
    rows: tuple[str, ...]
    columns: tuple[str, ...]
    entries: tuple[tuple[str, ...], ...]
    swap_trig: Callable[..., tuple[Any, ...]] | None = None

    def terms(self) -> list[tuple[int, int]]:
        return [
            (i, j)
            for i, row in enumerate(self.entries)
            for j, text in enumerate(row)
            if text not in ("0", "1")
        ]

    def symbolic(self, i: int, j: int) -> bool:
        return any(c.isalpha() for c in self.entries[i][j])


def _text(entries: tuple[tuple[str, ...], ...]) -> str:
    return "[" + ", ".join("[" + ", ".join(row) + "]" for row in entries) + "]"


def _negated(text: str) -> str:
    return text[1:] if text.startswith("-") else "-" + text


def _trig_swapped(text: str) -> str:
    return text.replace("cos", "COS").replace("sin", "cos").replace("COS", "sin")


def _entries_with(
    formula: MatrixFormula, chosen: Iterable[tuple[int, int]] | None, change: Callable[[str], str]
) -> tuple[tuple[str, ...], ...]:
    """The formula's entries with those ``chosen`` (all: None) changed."""
    marked = None if chosen is None else set(chosen)
    return tuple(
        tuple(
            change(text) if marked is None or (i, j) in marked else text
            for j, text in enumerate(row)
        )
        for i, row in enumerate(formula.entries)
    )


def matrix_mutations(formula: MatrixFormula) -> Iterator[Mutation]:
    """Sign flips of each column's, row's and single term's sign; each symbolic term (and
    column) missing; the transpose; rows and columns swapped; cos and sin swapped."""
    operation = OPERATION[formula.operation]
    shape = (len(formula.entries), len(formula.entries[0]))
    terms = formula.terms()
    seen: set[frozenset[tuple[int, int]]] = set()

    def sets(symbolic_only: bool) -> Iterator[tuple[str, str, frozenset[tuple[int, int]]]]:
        """Each column's and row's terms (and a row's derivatives, without its constant),
        then each term alone; a set met before keeps its first name."""
        usable = [t for t in terms if formula.symbolic(*t) or not symbolic_only]
        for j, column in enumerate(formula.columns):
            chosen = frozenset(t for t in usable if t[1] == j)
            if len(chosen) > 1:
                yield f"column_{column}", f"its {column} column", chosen
        for i, row in enumerate(formula.rows):
            chosen = frozenset(t for t in usable if t[0] == i)
            if len(chosen) > 1:
                yield f"row_{row}", f"its {row} row", chosen
            symbolic = frozenset(t for t in chosen if formula.symbolic(*t))
            if len(symbolic) > 1 and symbolic != chosen:
                yield f"row_{row}_derivatives", f"its {row} row's derivatives", symbolic
        for i, j in usable:
            entry = formula.entries[i][j]
            yield (
                f"{formula.rows[i]}_{formula.columns[j]}",
                f"its entry {entry}",
                frozenset({(i, j)}),
            )

    for name, what, chosen in sets(symbolic_only=False):
        if not chosen or chosen in seen:
            continue
        seen.add(chosen)
        mask = np.zeros(shape)
        for i, j in chosen:
            mask[i, j] = 1.0
        shown = _entries_with(formula, chosen, _negated)
        yield Mutation(formula.operation, f"sign_{name}", "sign",
                       f"{operation.title} has the sign of {what} flipped: {_text(shown)}",
                       f"{operation.equation}", result(flipped(mask)))  # fmt: skip
    seen.clear()
    for name, what, chosen in sets(symbolic_only=True):
        if not chosen or chosen in seen:
            continue
        seen.add(chosen)
        mask = np.zeros(shape)
        for i, j in chosen:
            mask[i, j] = 1.0
        shown = _entries_with(formula, chosen, lambda text: "0")
        yield Mutation(formula.operation, f"missing_{name}", "missing",
                       f"{operation.title} lacks {what}: {_text(shown)}",
                       f"{operation.equation}", result(zeroed(mask)))  # fmt: skip
    if shape[0] == shape[1]:
        shown = tuple(zip(*formula.entries, strict=True))
        yield Mutation(formula.operation, "transposed", "transpose",
                       f"{operation.title} is used transposed: {_text(shown)}",
                       f"{operation.equation}", result(lambda value: value.T))  # fmt: skip
    if shape[0] == 2:
        shown = formula.entries[::-1]
        yield Mutation(formula.operation, "rows_swapped", "transpose",
                       f"{operation.title} has its rows in the order ({formula.rows[1]},"
                       f" {formula.rows[0]}): {_text(shown)}", f"{operation.equation}",
                       result(lambda value: value[::-1]))  # fmt: skip
    if shape[1] == 2:
        shown = tuple(row[::-1] for row in formula.entries)
        yield Mutation(formula.operation, "columns_swapped", "transpose",
                       f"{operation.title} has its columns in the order ({formula.columns[1]},"
                       f" {formula.columns[0]}): {_text(shown)}", f"{operation.equation}",
                       result(lambda value: value[:, ::-1]))  # fmt: skip
    if formula.swap_trig is not None:
        shown = _entries_with(formula, None, _trig_swapped)
        yield Mutation(formula.operation, "cos_sin_swapped", "swapped",
                       f"{operation.title} has cos and sin swapped: {_text(shown)}",
                       f"{operation.equation}", operands(formula.swap_trig),
                       ("sin", "cos"))  # fmt: skip


def heading_swapped(pose: FloatArray, d: float) -> tuple[FloatArray, float]:
    return turned(pose, math.pi / 2), d


def angle_swapped(pose: FloatArray, z: FloatArray) -> tuple[FloatArray, FloatArray]:
    """cos and sin of theta + beta swapped: theta' = pi/2 - theta - 2 beta."""
    return turned(pose, math.pi / 2 - 2.0 * float(z[0])), z


# -- a noise matrix scaled: one mutation per operation that takes one ----------------------


@dataclass(frozen=True, slots=True)
class NoiseUse:
    """An operation that takes a noise matrix (or makes one: ``operand`` None).

    :param operand: the index of the noise among the operation's operands
    :param symbol: ``Q`` or ``R``
    :param where: where the scaled noise shows, after "in" ("S", "every use")
    :param equation: the operation's equation with the noise scaled by k
    """

    operation: str
    operand: int | None
    symbol: str
    where: str
    equation: str


def times(k: float) -> str:
    """A factor as a sentence says it: "10 times too large", "4 times too small"."""
    if k >= 1.0:
        return f"{k:.3g} times too large"
    return f"{1.0 / k:.3g} times too small"


def _scaled_operand(index: int) -> Apply:
    def apply(rerun: Rerun, function: Callable[..., Any], operands: tuple[Any, ...]) -> Any:
        changed = list(operands)
        changed[index] = rerun.scale * np.asarray(changed[index], dtype=np.float64)
        return function(*changed)

    return apply


def _scaled_result(rerun: Rerun, function: Callable[..., Any], operands: tuple[Any, ...]) -> Any:
    return rerun.scale * np.asarray(function(*operands), dtype=np.float64)


def scaled_noise(use: NoiseUse) -> Mutation:
    """The mutation of ``use`` with its noise k times what it is (k read off the filter's
    result by the search: :mod:`ekfviz.check.scaling`)."""
    name = "scaled" if use.operand is None else "noise_scaled"
    apply = _scaled_result if use.operand is None else _scaled_operand(use.operand)

    def says(k: float) -> str:
        return (f"{use.symbol} is used {times(k)} in {use.where}:"
                f" {use.equation.replace('k ', f'{k:.3g} ')}")  # fmt: skip

    return Mutation(use.operation, name, "scale",
                    f"{use.symbol} is used k times too large or too small (k not 1) in"
                    f" {use.where}: {use.equation}", OPERATION[use.operation].equation, apply,
                    ("*",), says=says)  # fmt: skip


# -- the other operations, one by one ---------------------------------------------------------

DEG = math.pi / 180.0


def written(operation: str, name: str, family: str, wrong: str, apply: Apply, *,
       fix: str = "", tokens: tuple[str, ...] = (), when: str = "") -> Mutation:  # fmt: skip
    """A mutation whose fix, unless given, is its operation's equation."""
    return Mutation(operation, name, family, wrong, fix or OPERATION[operation].equation, apply,
                    tokens, when)  # fmt: skip


# -- what the appliers share ---------------------------------------------------------------------


def with_heading(pose: FloatArray, theta: float, *, wrap: bool = True) -> FloatArray:
    moved = np.array(pose, dtype=np.float64)
    moved[2] = wrap_angle(theta) if wrap else theta
    return moved


def reflected(moved: FloatArray, pose: FloatArray, axis: int) -> FloatArray:
    """The motion with its step along ``axis`` subtracted instead of added."""
    reflected = np.array(moved, dtype=np.float64)
    reflected[axis] = 2.0 * pose[axis] - moved[axis]
    return reflected


def with_bearing(value: FloatArray, bearing: float) -> FloatArray:
    changed = np.array(value, dtype=np.float64)
    changed[0] = bearing
    return changed


def blocked(flat: FloatArray) -> FloatArray:
    """A line [b1, r1, ..., bk, rk] as a reader of [b1..bk, r1..rk] lays it out."""
    m = len(flat) // 2
    return np.column_stack([flat[:m], flat[m:]]).reshape(-1)


def norm(offset: FloatArray) -> float:
    return math.hypot(float(offset[0]), float(offset[1]))


def bearing_sign(H: FloatArray, j: int) -> FloatArray:
    flipped = np.array(H)
    for column in (0, 1, j, j + 1):
        flipped[0, column] = -flipped[0, column]
    return flipped


def joseph(P: FloatArray, K: FloatArray, H: FloatArray) -> FloatArray:
    IKH = np.eye(len(P)) - K @ H
    joseph: FloatArray = IKH @ P @ IKH.T
    return joseph


def same_size(stale: FloatArray, current: FloatArray) -> FloatArray:
    """The stale P where it covers the same state as the current one."""
    if stale.shape != current.shape:
        raise IndexError("the state grew within the line")
    return stale


def declared(declared: FloatArray | None, value: FloatArray) -> FloatArray:
    """The filter's declared noise where it differs from the run's (else this mutation is
    the reference itself, and reproduces nothing more)."""
    if declared is None or declared.shape != value.shape or np.allclose(declared, value):
        raise ValueError("no declared noise of its own")
    return declared


def own_motion_noise(rerun: Rerun, function: Callable[..., Any], Q: FloatArray) -> FloatArray:
    """The filter's own Q, read off its pose block: W^-1 (P_rr' - G P_rr G^T) W^-T where
    that is a diagonal covariance other than the run's (a noise in the robot frame), or
    the same where P_rr' - G P_rr G^T itself is diagonal (a noise added in the world
    frame, unrotated)."""
    target, before = rerun.target, rerun.before
    if target is None or before is None or target.P.shape != before.P.shape:
        raise ValueError("no result to read the noise off")
    G, W = rerun.G, rerun.W
    added = target.P[:3, :3] - G @ before.P[:3, :3] @ G.T
    added = 0.5 * (added + added.T)
    own = np.linalg.solve(W, np.linalg.solve(W, added).T).T
    own = 0.5 * (own + own.T)
    if not (_diagonal_covariance(own) or _diagonal_covariance(added)):
        raise ValueError("the noise added is not a diagonal covariance")
    if np.allclose(own, Q, rtol=1e-9, atol=1e-15):
        raise ValueError("the run's own noise")
    return np.asarray(own, dtype=np.float64)


def _diagonal_covariance(matrix: FloatArray) -> bool:
    """Whether ``matrix`` (n x n) is diagonal, to 1e-6 of its largest entry, and not negative."""
    scale = max(float(np.abs(matrix).max()), 1e-300)
    off = matrix - np.diag(np.diag(matrix))
    return bool(np.abs(off).max() <= 1e-6 * scale and np.diag(matrix).min() >= 0.0)


def constant_landmark_covariance(
    rerun: Rerun, function: Callable[..., Any], *operands: Any
) -> FloatArray:
    """The filter's covariance of its new landmarks where it is one diagonal constant for
    all of the line's new landmarks."""
    target = rerun.target
    if target is None or not rerun.new_ids:
        raise ValueError("no result to read the covariance off")
    where = {int(i): k for k, i in enumerate(target.ids.tolist())}
    blocks = []
    for landmark_id in rerun.new_ids:
        if landmark_id not in where:
            raise ValueError("a new landmark the filter has not")
        k = 3 + 2 * where[landmark_id]
        blocks.append(target.P[k : k + 2, k : k + 2])
    first = blocks[0]
    scale = max(1e-12, float(np.abs(first).max()))
    if abs(first[0, 1]) > 1e-9 * scale or any(
        np.abs(b - first).max() > 1e-9 * scale for b in blocks
    ):
        raise ValueError("not one constant diagonal block")
    return np.array(first)
