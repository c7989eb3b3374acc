"""The probes of ``check``'s catalogue: which events a mutation acts on, and what it does
to a fixed set of events of every kind, which tells the mutations apart.

Two mutations that change every probe event alike are one cause (the catalogue's first of
them stands for the others); one that changes none is no cause at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from ekfviz.check.mutations import MUTATIONS, Mutation
from ekfviz.check.rerun import RERUN_ERRORS, Form, Noise, Rerun, State, Step
from ekfviz.models.angles import wrap_angle

MUTATION_BY_ID: dict[str, Mutation] = {m.id: m for m in MUTATIONS}


def acts_on(mutation: Mutation, step: Step, before: State) -> bool:
    """Whether ``mutation`` can change ``step`` from ``before`` at all."""
    event = mutation.event
    if step.is_predict:
        if event != "predict":
            return False
        if mutation.when == "still":
            return step.d == 0.0 and step.alpha == 0.0
        if mutation.when == "not_driving":
            return step.d == 0.0
        return True
    if event == "predict" or mutation.family == "form":
        return False
    assert step.ids is not None
    known_ids = set(before.ids.tolist())
    line = step.ids.tolist()
    has_known = any(i in known_ids for i in line)
    has_new = any(i not in known_ids for i in line)
    if mutation.operation == "measurement_noise":
        return True
    if mutation.id in ("update_loop.init_in_line_order", "init_pose.before_line"):
        return has_known and has_new
    if mutation.id == "update_loop.update_at_init":
        return has_new
    return has_new if event == "init" else has_known


@cache
def breadth(mutation_id: str) -> int:
    """How many probe events a mutation changes."""
    return sum(1 for k, r in zip(fingerprint(mutation_id), fingerprint(""), strict=False)
               if k not in (b"", r))  # fmt: skip


@dataclass(frozen=True, slots=True)
class Classes:
    """What the probes tell of the catalogue (see :func:`classes`).

    :param representative: each mutation no event tells from an earlier one of the
        catalogue, mapped to that one
    :param inert: the mutations that change no event at all (a sign of a column of J_z,
        which R's diagonal hides; a heading wrapped otherwise, which check compares
        modulo 2 pi): no cause ``check`` can name
    """

    representative: dict[str, str]
    inert: frozenset[str]


@cache
def fingerprint(mutation_id: str) -> tuple[bytes, ...]:
    """What a mutation (empty: none) does to each probe event of :func:`_probes` (empty
    where it cannot act): two mutations of the same fingerprint change every event the
    same way (the heading compared modulo 2 pi, as check compares it), and are one cause.
    The mutations that read the filter's own result are their own (no fingerprint)."""
    if not mutation_id:
        return tuple(_fingerprint([], before, step) for before, step in _probes())
    mutation = MUTATION_BY_ID[mutation_id]
    if mutation.family in ("own", "form"):
        return (mutation_id.encode(),)
    return tuple(
        _fingerprint([mutation], before, step) if acts_on(mutation, step, before) else b""
        for before, step in _probes()
    )


def is_inert(mutation_id: str) -> bool:
    """Whether a mutation changes no probe event at all (see :class:`Classes`)."""
    return all(
        k in (b"", r) for k, r in zip(fingerprint(mutation_id), fingerprint(""), strict=False)
    )


def classes() -> Classes:
    """The whole catalogue's classes (its table and coverage; a run asks :func:`fingerprint`
    of the mutations it meets only)."""
    representative: dict[str, str] = {}
    inert: set[str] = set()
    seen: dict[tuple[bytes, ...], str] = {}
    for mutation in MUTATIONS:
        if is_inert(mutation.id):
            inert.add(mutation.id)
            continue
        first = seen.setdefault(fingerprint(mutation.id), mutation.id)
        if first != mutation.id:
            representative[mutation.id] = first
    return Classes(representative, frozenset(inert))


def _fingerprint(mutations: list[Mutation], before: State, step: Step) -> bytes:
    try:
        result = Rerun.with_mutations(_PROBE_NOISE, mutations, Form(), None).run(before, step)
    except RERUN_ERRORS:
        return b"error"
    x = result.x.copy()
    x[2] = wrap_angle(float(x[2]))
    values = np.concatenate([x, result.P.ravel()])
    return np.round(values, 9).tobytes()


_PROBE_NOISE = Noise(np.diag([0.0625, 0.01, 0.01]), np.diag([1e-4, 0.0064]))


def _probes() -> list[tuple[State, Step]]:
    """Events of every kind from random states (a fixed seed): see :func:`fingerprint`."""
    rng = np.random.default_rng(20261)
    probes = []
    for heading in (0.4, 2.9, -2.2):
        pose = np.array([0.3, -0.2, heading])
        # ahead-left, right behind (its bearing about pi), to the right, behind-right
        directions = heading + np.array([0.6, math.pi - 0.01, -1.2, -2.5])
        ranges = np.array([5.0, 6.0, 7.0, 4.5])
        landmarks = pose[:2] + ranges[:, None] * np.column_stack(
            [np.cos(directions), np.sin(directions)]
        )
        x = np.concatenate([pose, landmarks.ravel()])
        A = rng.normal(size=(len(x), len(x)))
        P = A @ A.T / len(x) * 0.05 + np.diag(np.full(len(x), 0.01))
        ids = np.array([3, 5, 8, 9])
        s = State(x, P, ids)
        seen = np.column_stack([directions - heading + rng.normal(0.0, 0.05, 4),
                                ranges + rng.normal(0.0, 0.1, 4)])  # fmt: skip
        seen[1, 0] = -math.pi + 0.02  # across +-pi from the predicted bearing
        seen[:, 0] = [wrap_angle(b) for b in seen[:, 0]]
        mixed = np.vstack([seen[1], [0.7, 4.0], seen[0], [-2.5, 6.0]])
        first = np.array([[0.5, 5.0], [-2.8, 4.0], [2.0, 7.0]])
        empty = State(x[:3].copy(), P[:3, :3].copy(), np.zeros(0, dtype=np.int64))
        probes += [
            (s, Step(d=1.3, alpha=0.4)),
            (s, Step(d=0.8, alpha=-2.0)),
            (s, Step(d=0.0, alpha=0.0)),
            (s, Step(d=0.0, alpha=0.3)),
            (s, Step(ids=ids, z=seen)),
            (s, Step(ids=np.array([5, 11, 3, 12]), z=mixed)),
            (empty, Step(ids=np.array([1, 2, 3]), z=first)),
        ]
    return probes
