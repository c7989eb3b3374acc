"""Diagnosis as a search: the smallest set of mutations that reproduces what a filter did.

At a divergent event, :class:`Diagnosis` re-runs the event from the filter's own state
before it (:class:`~ekfviz.check.rerun.Rerun`) with the mutations already found in the
run, then with one more, then with two more (the mutations that move the result towards
the filter's first), in the filter's own form of the update (sequential or joint,
detected at the first line that tells them apart; the covariance update as (I - K H) P,
P - K S K^T or Joseph's, which agree for a right gain only). A set reproduces the event
when the filter's whole result (mean, covariance, landmark ids) is within ten times the
tolerance. The smallest such set is named; sets that no event of the run can tell apart
(:func:`fingerprint`) are one cause; where sets that differ elsewhere reproduce one
event equally, the events the filter got right refute those that would have changed
them (:meth:`Diagnosis.resolve`), and what is left is said as the alternatives.

A state already invalid (not positive semi-definite, or variances beyond any the run
could make) is the doing of the mistakes found before it: a later event from it is
theirs, not a new cause's.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ekfviz.check.mutations import INERT, MUTATIONS, Mutation
from ekfviz.check.probes import MUTATION_BY_ID, acts_on, breadth, fingerprint
from ekfviz.check.rerun import (
    FORMS,
    PROBE_SCALE,
    RERUN_ERRORS,
    Form,
    Noise,
    Rerun,
    State,
    Step,
)
from ekfviz.check.scaling import fit_scale
from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle

# the families of mutations that read a quantity off the filter's result (its own noise, a
# noise's factor): any set they complete may fit, so a specific one is named before them
FITTED = frozenset({"own", "scale"})
# the operations whose mutations make K other than P H^T (H P H^T + R)^-1: only with them
# do the forms of the covariance update differ
_GAIN_OPERATIONS = frozenset({"innovation_covariance", "kalman_gain"})
_GAIN_MUTATIONS = frozenset({"update_loop.stale_covariance"})
# the operations whose mutations may move h(x)'s bearing where no wrap meets it: only with
# them does a bearing h(x) wrapped or not differ
_BEARING_OPERATIONS = frozenset({"expected_measurement", "innovation"})
# the operations whose mutations may leave P asymmetric within a line: only with them does
# a filter that symmetrises P after each landmark differ from one that does not
_ASYMMETRIC_OPERATIONS = frozenset({"corrected_covariance"})
# how many single mutations (the ones that bring the result nearest the filter's) pairs
# are made of; and how many of the nearest a deeper search adds one at a time (see
# Diagnosis._beam)
PAIR_CANDIDATES = 20
COMPLETED_CANDIDATES = 10  # the nearest singles a fitted mutation completes, alone or paired
TRIPLE_ANCHORS = 3
SECOND_ANCHORS = 2
BEAM_CANDIDATES = 60  # the nearest singles the deeper search adds, one at a time
DEEP_SEARCHES = 1
# a variance this many times the square of the state's extent is beyond any a run makes
INVALID_VARIANCE = 1e12
# metres: a position beyond this is no robot's (10,000 km), but a filter's that has lost
# its map (an update that pushes the mean away, event after event)
FAR = 1e7
# the smallest eigenvalue of a valid P to its largest: below it, P is singular to
# float64's precision (a correct filter's P keeps the prior's rank and R's)
SINGULAR = 1e-13
# the share of a divergence the mistakes found may leave unexplained at a later event
# (see Diagnosis._nearly)
UNEXPLAINED_SHARE = 1e-3
# how many events of each kind (predict, update) the mistakes found do not explain get a
# search of one more (later ones are unknown but for the mistakes found: a second mistake
# shows at the first events of its kind), of two more, and of three more
FULL_SEARCHES = 3
PAIR_SEARCHES = 3


@dataclass(frozen=True, slots=True)
class Finding:
    """What reproduces one divergent event.

    :param causes: the mutations' ids (with a form of the update the reference does not
        use, its pseudo-mutation: ``update_loop.joint``); empty where nothing does
    :param alternatives: other sets that reproduce the event as well, where neither this
        event nor the rest of the run tells them apart (``causes`` is then the first)
    :param inherited: the causes are the earlier events' mistakes: the state before the
        event was already invalid, or they explain it but for round-off (an ill-conditioned
        state of their making)
    :param detail: what a mutation read off the filter (its own noise's sigmas)
    :param indistinct: the sets no event of the run tells from ``causes`` (named as the
        broadest of them)
    :param scales: each scaled-noise cause's factor k, as read off the filter's result
    """

    causes: tuple[str, ...] = ()
    alternatives: tuple[tuple[str, ...], ...] = ()
    inherited: bool = False
    detail: str = ""
    indistinct: tuple[tuple[str, ...], ...] = ()
    scales: tuple[tuple[str, float], ...] = ()

    @property
    def known(self) -> bool:
        return bool(self.causes) and not self.alternatives


@dataclass(frozen=True, slots=True)
class Seen:
    """One event of the run as the search may look back at it: the filter's state before
    and after it, and what explained it (nothing where the filter matched the reference)."""

    step: Step
    before: State
    after: State
    explained_by: tuple[str, ...] = ()


@dataclass(slots=True)
class Diagnosis:
    """The search over one run (see the module); what it finds carries over event to event.

    :param reference: the form of the update the reference uses (``--update``)
    """

    noise: Noise
    reference: Form
    tolerance: float
    found: dict[str, Mutation] = field(default_factory=dict)
    joint: bool | None = None  # the filter's mode of update, once a line has told it
    deep_left: int = DEEP_SEARCHES
    pairs_left: int = PAIR_SEARCHES
    searches_left: dict[str, int] = field(default_factory=dict)
    # the causes named among equals, and the options the log had not told them from
    undecided: dict[tuple[str, ...], tuple[tuple[str, ...], ...]] = field(default_factory=dict)
    # the factor of each scaled noise found (where the next event's fit starts)
    scales: dict[str, float] = field(default_factory=dict)

    def explain(
        self,
        before: State,
        after: State,
        step: Step,
        divergence: float = 0.0,
        history: Sequence[Seen] = (),
    ) -> Finding:
        """The smallest set of mutations (with those found so far) that reproduces the
        filter's result ``after`` of ``step`` from ``before``; where several do, those
        the earlier events of ``history`` refute are dropped."""
        close = max(self.tolerance * 10, 1e-8, 1e-9 * divergence)
        trial = _Trial(self.noise, before, after, step, close, self.scales)
        base = [m for m in self.found.values() if acts_on(m, step, before)]
        forms = self._forms(step, before)
        hit = trial.first(base, forms)
        if hit is None:
            base, hit = self._swapped(trial, base, forms)
        if hit is not None:
            needed = _minimal(trial, base, hit)
            if needed or not (self.found and invalid(before)):
                return self._named([needed], hit, trial, history)
            # the filter did what the operations say; the reference skipped what an invalid
            # state (of the mistakes found's making) does not allow (an S not definite)
            return Finding(tuple(self.found), inherited=True)
        if self.found and invalid(before):  # of the earlier mistakes' making, whatever kind
            return Finding(tuple(self.found), inherited=True)
        if base and self._nearly(trial, base, forms):
            return Finding(tuple(m.id for m in base), inherited=True)
        kind = _kind(step)
        if self.searches_left.get(kind, FULL_SEARCHES) <= 0:
            return Finding()
        self.searches_left[kind] = self.searches_left.get(kind, FULL_SEARCHES) - 1
        taken = {m.operation for m in base}
        candidates = [
            m
            for m in MUTATIONS
            if m.family != "form"
            and m.id not in INERT
            and m.operation not in taken
            and acts_on(m, step, before)
        ]
        found_sets, hit_form = self._search(trial, base, candidates, forms)
        if not found_sets:
            return Finding()
        assert hit_form is not None
        return self._named(found_sets, hit_form, trial, history)

    @staticmethod
    def _nearly(trial: _Trial, base: list[Mutation], forms: list[Form]) -> bool:
        """Whether the mistakes found explain all but :data:`UNEXPLAINED_SHARE` of how far
        the filter is from the reference: what is left is the round-off of a state they
        have made ill-conditioned (an S near singular), not a cause of its own."""
        with_base = trial.best(base, forms).distance
        without = trial.best([], forms[:1]).distance
        return math.isfinite(without) and with_base <= UNEXPLAINED_SHARE * without

    def _swapped(
        self, trial: _Trial, base: list[Mutation], forms: list[Form]
    ) -> tuple[list[Mutation], Form | None]:
        """``base`` with a cause named among equals (:attr:`Finding.indistinct`) swapped for
        one of the options it could not then be told from, where that reproduces the
        event (which tells them apart: the option is kept from now on); else ``base``."""
        for chosen, others in list(self.undecided.items()):
            if not any(m.id in chosen for m in base):
                continue
            kept = [m for m in base if m.id not in chosen]
            for option in others:
                mutations = [MUTATION_BY_ID[c] for c in option]
                hit = trial.first(kept + mutations, forms)
                if hit is None:
                    continue
                for cause in chosen:
                    self.found.pop(cause, None)
                self._keep(mutations)
                del self.undecided[chosen]
                rest = tuple(o for o in others if o != option)
                if rest:
                    self.undecided[tuple(option)] = rest
                return kept + mutations, hit
        return base, None

    def _forms(self, step: Step, before: State) -> list[Form]:
        """The forms of the update to try: in the filter's mode, once known; else in the
        reference's first, then the other mode where the line has two known landmarks."""
        if step.is_predict:
            return [Form()]
        assert step.ids is not None
        known = sum(1 for i in step.ids.tolist() if i in set(before.ids.tolist()))
        modes = [self.reference.joint] + ([not self.reference.joint] if known > 1 else [])
        if self.joint is not None:  # the filter's own, once a line has told
            modes = [self.joint]
        return [Form(joint, form.covariance) for joint in modes for form in FORMS]

    def _search(
        self, trial: _Trial, base: list[Mutation], candidates: list[Mutation], forms: list[Form]
    ) -> tuple[list[list[Mutation]], Form | None]:
        """The sets of one, two (or, at the first unexplained events, three) more mutations
        beside ``base`` that reproduce the event, all of the smallest size; and the form.
        Each size is tried in the reference's mode of update before the other one; pairs
        of the singles that come nearest the filter's result, triples of one of the
        nearest and a pair of those nearest beside it."""
        modes = sorted({form.joint for form in forms}, key=lambda joint: joint != forms[0].joint)
        by_mode = {joint: [f for f in forms if f.joint == joint] for joint in modes}
        ranked: dict[bool, list[Mutation]] = {}
        for joint in modes:
            reached, form_of, ranked[joint] = self._singles(trial, base, candidates, by_mode[joint])
            if reached:
                return reached, form_of
        if self.pairs_left <= 0:
            return [], None
        self.pairs_left -= 1
        for joint in modes:
            reached, form_of = _combinations(trial, base, ranked[joint][:PAIR_CANDIDATES], 2,
                                             by_mode[joint])  # fmt: skip
            if reached:
                return reached, form_of
        fitted = [m for m in candidates if m.family in FITTED]
        plain = [m for m in candidates if m.family not in FITTED]
        for joint in modes:
            reached, form_of = _completed(trial, base, plain, fitted, by_mode[joint])
            if reached:
                return reached, form_of
        if self.deep_left <= 0:
            return [], None
        self.deep_left -= 1
        first = modes[0]  # three mistakes at once: in the likelier mode only
        return self._beam(trial, base, candidates, by_mode[first], ranked[first])

    def _beam(
        self,
        trial: _Trial,
        base: list[Mutation],
        candidates: list[Mutation],
        forms: list[Form],
        ranked: list[Mutation],
    ) -> tuple[list[list[Mutation]], Form | None]:
        """Sets of two or three more mutations, one at a time: beside each of the nearest
        singles (an anchor), each of the :data:`BEAM_CANDIDATES` nearest again, then beside
        each of the nearest of those, each once more (a mistake whose effect the others
        hide ranks high once they are in). A mutation that reads its value off the filter's
        result (its own noise) and could not alone is beside every anchor too."""
        alone = set(map(id, ranked))
        shortlist = ranked[:BEAM_CANDIDATES] + [m for m in candidates if id(m) not in alone]
        for anchor in ranked[:TRIPLE_ANCHORS]:
            chain = [*base, anchor]
            beside = [m for m in shortlist if m.operation != anchor.operation]
            reached, form_of, nearest = self._singles(trial, chain, beside, forms)
            if reached:
                return reached, form_of
            for second in nearest[:SECOND_ANCHORS]:
                rest = [m for m in beside if m.operation != second.operation]
                reached, form_of, _ = self._singles(trial, [*chain, second], rest, forms)
                if reached:
                    return reached, form_of
        return [], None

    @staticmethod
    def _singles(
        trial: _Trial, base: list[Mutation], candidates: list[Mutation], forms: list[Form]
    ) -> tuple[list[list[Mutation]], Form | None, list[Mutation]]:
        """The sets of one more mutation that reproduce the event; and the rest, nearest
        first: by turns the one whose change best points the way of the filter's (the
        cosine of the two) and the one that leaves the least of it (the length of what
        is left), so that a mistake whose effect a second one hides still ranks high."""
        reached: list[list[Mutation]] = []
        form_of: Form | None = None
        scored: list[tuple[float, float, Mutation]] = []
        origin = trial.run(base, forms[0])
        for mutation in candidates:
            result = trial.best([*base, mutation], forms)
            if result.form is not None:
                reached.append([*base, mutation])
                form_of = form_of or result.form
            elif origin is not None and result.state is not None:
                cosine, left = trial.relevance(origin, result.state)
                scored.append((cosine, left, mutation))
        return reached, form_of, _nearest_first(scored)

    def _named(
        self, sets: list[list[Mutation]], form: Form, trial: _Trial, history: Sequence[Seen]
    ) -> Finding:
        """The finding of the reproducing ``sets``: one cause where they are one class; of
        several, those ``history`` does not refute (a specific mutation before one that
        reads the filter's own quantity), the broadest of them named and the others kept
        as what the log has not told it from (:meth:`resolve` looks again at the end); the
        form noted, the causes named kept for the events after."""
        distinct: dict[tuple[tuple[bytes, ...], ...], list[Mutation]] = {}
        smallest_size = min(len(chosen) for chosen in sets)
        sets = [chosen for chosen in sets if len(chosen) == smallest_size]
        for chosen in sets if len(sets) > 1 else ():  # (a class's first stands for it)
            key = tuple(sorted(fingerprint(m.id) for m in chosen))
            distinct.setdefault(key, chosen)
        options = sorted(distinct.values() if distinct else sets,
                         key=lambda s: (len(s), [m.id for m in s]))  # fmt: skip
        smallest = [s for s in options if len(s) == len(options[0])]
        for option in smallest:  # (their factors, for the events that may refute them)
            self.scales.update(trial.scales_of(option))
        smallest = self._unrefuted(smallest, history)
        specific = [s for s in smallest if not any(m.family in FITTED for m in s)]
        smallest = _broadest_first(specific or smallest)
        if not trial.step.is_predict and self.joint is None and trial.decides_mode():
            self.joint = form.joint
        self._keep(smallest[0])
        chosen = smallest[0]
        causes = [m.id for m in chosen]
        if not trial.step.is_predict and form.joint != self.reference.joint:
            causes.append("update_loop.joint" if form.joint else "update_loop.sequential")
        detail = _detail(chosen, trial, form)
        others = tuple(tuple(m.id for m in s) for s in smallest[1:])
        if others:
            self.undecided[tuple(m.id for m in chosen)] = others
        scales = trial.scales_of(chosen)
        self.scales.update(scales)
        return Finding(tuple(causes), (), detail=detail, indistinct=others,
                       scales=tuple(scales.items()))  # fmt: skip

    def _keep(self, mutations: Iterable[Mutation]) -> None:
        for mutation in mutations:
            if mutation.family != "form":
                self.found.setdefault(mutation.id, mutation)

    def _unrefuted(
        self, options: list[list[Mutation]], history: Sequence[Seen]
    ) -> list[list[Mutation]]:
        """The ``options`` no event of ``history`` refutes (all of them where it refutes
        every one): an option is refuted by an event it acts on that, re-run with what
        explained it (nothing: the filter matched) and the option, is no longer
        reproduced (an option re-run in place of its rivals where one of them explained
        it)."""
        if len(options) < 2:
            return options
        rivals = {m.id for option in options for m in option}
        kept = [
            option
            for option in options
            if not any(
                _refutes(self.noise, option, seen, self.tolerance, self.scales, rivals)
                for seen in history
            )
        ]
        return kept or options

    def resolve(self, finding: Finding, history: Sequence[Seen]) -> Finding:
        """``finding`` looked at again with the whole run's ``history``: of its cause and
        the options the log had not told from it when it was named, those the history
        does not refute, the broadest first."""
        if not finding.indistinct:
            return finding
        form_causes = tuple(c for c in finding.causes if MUTATION_BY_ID[c].family == "form")
        named = tuple(c for c in finding.causes if c not in form_causes)
        options = [[MUTATION_BY_ID[c] for c in option] for option in (named, *finding.indistinct)]
        options = _broadest_first(self._unrefuted(options, history))
        self._keep(options[0])
        left = tuple(tuple(m.id for m in option) for option in options[1:])
        causes = tuple(m.id for m in options[0]) + form_causes
        return Finding(causes, (), finding.inherited, finding.detail, left, finding.scales)


def _broadest_first(options: list[list[Mutation]]) -> list[list[Mutation]]:
    """``options`` ordered by how many kinds of event they change, the most first (R's
    sigmas everywhere before S's alone: the one that explains the most), in catalogue
    order among equals."""
    return sorted(options, key=lambda option: -sum(breadth(m.id) for m in option))


@dataclass(frozen=True, slots=True)
class _Result:
    form: Form | None  # the form that reproduces the event, None where none does
    distance: float  # else how near the nearest came (the largest scaled difference)
    state: State | None = None  # the nearest re-run's result


def _nearest_first(scored: list[tuple[float, float, Mutation]]) -> list[Mutation]:
    """The mutations of (cosine, length left, mutation) by turns the one whose change best
    points the way of the filter's and the one that leaves the least of it."""
    by_cosine = [m for _, _, m in sorted(scored, key=lambda t: -t[0])]
    by_left = [m for _, _, m in sorted(scored, key=lambda t: t[1])]
    nearest: list[Mutation] = []
    for pair in zip(by_cosine, by_left, strict=True):
        for mutation in pair:
            if mutation not in nearest:
                nearest.append(mutation)
    return nearest


def _completed(
    trial: _Trial,
    base: list[Mutation],
    candidates: list[Mutation],
    fitted: list[Mutation],
    forms: list[Form],
) -> tuple[list[list[Mutation]], Form | None]:
    """The sets of one, else two, of ``candidates`` and one of ``fitted`` (a mutation that
    reads its quantity off the filter's result) beside ``base`` that reproduce the event;
    and the form. A fitted one reproduces nothing while another mistake is left, so it
    never ranks by itself; and what it reads off hides whatever else differs where it
    reaches: the others are ranked by the filter's change outside its reach, the nearest
    :data:`COMPLETED_CANDIDATES` of them completed by it."""
    origin = trial.run(base, forms[0])
    if origin is None:
        return [], None
    nearest: dict[str, list[Mutation]] = {}
    for last in fitted:
        outside = trial.outside_reach(origin, base, last, forms[0])
        scored = []
        for mutation in candidates:
            state = trial.run([*base, mutation], forms[0])
            if mutation.operation != last.operation and state is not None:
                scored.append((*trial.relevance(origin, state, outside), mutation))
        nearest[last.id] = _nearest_first(scored)[:COMPLETED_CANDIDATES]
    for size in (1, 2):
        reached: list[list[Mutation]] = []
        form_of: Form | None = None
        for last in fitted:
            for combo in itertools.combinations(nearest[last.id], size):
                if len({m.operation for m in combo}) < size:
                    continue
                result = trial.best([*base, *combo, last], forms)
                if result.form is not None:
                    reached.append([*base, *combo, last])
                    form_of = form_of or result.form
        if reached:
            return reached, form_of
    return [], None


def _combinations(
    trial: _Trial, base: list[Mutation], ranked: list[Mutation], size: int, forms: list[Form]
) -> tuple[list[list[Mutation]], Form | None]:
    """The sets of ``size`` more of ``ranked`` (of different operations) beside ``base``
    that reproduce the event; and the form."""
    reached: list[list[Mutation]] = []
    form_of: Form | None = None
    for combo in itertools.combinations(ranked, size):
        if len({m.operation for m in combo}) < size:
            continue
        result = trial.best([*base, *combo], forms)
        if result.form is not None:
            reached.append([*base, *combo])
            form_of = form_of or result.form
    return reached, form_of


class _Trial:
    """The re-runs of one event against the filter's result."""

    def __init__(
        self,
        noise: Noise,
        before: State,
        after: State,
        step: Step,
        close: float,
        starts: dict[str, float] | None = None,
        *,
        fit: bool = True,
    ):
        self.noise, self.before, self.after, self.step, self.close = (
            noise,
            before,
            after,
            step,
            close,
        )
        self._modes_differ: bool | None = None
        # a scaled noise's factor: where its fit starts (or, not fitted, the one it takes),
        # and what it found for each set
        self.starts, self.fit = starts or {}, fit
        self.scales: dict[tuple[str, ...], float] = {}
        self._runs: dict[tuple[tuple[str, ...], Form], State | None] = {}

    def run(self, mutations: Sequence[Mutation], form: Form) -> State | None:
        """The event re-run with ``mutations`` in ``form``; a scaled noise's factor fitted
        to the filter's result (one at most a set); None where it cannot run."""
        scaled = [m for m in mutations if m.family == "scale"]
        if not scaled:
            key = (_key(mutations), form)
            if key not in self._runs:
                self._runs[key] = self._run(mutations, form, PROBE_SCALE)
            return self._runs[key]
        if len(scaled) > 1:
            return None
        start = self.starts.get(scaled[0].id, 1.0)
        if not self.fit:
            return self._run(mutations, form, start)
        fitted = fit_scale(lambda k: self._run(mutations, form, k), self.after, self.close, start)
        if fitted is None:
            return None
        self.scales[_key(mutations)] = fitted[0]
        return fitted[1]

    def scales_of(self, mutations: Sequence[Mutation]) -> dict[str, float]:
        """The factors of the scaled noises of ``mutations`` as fitted last."""
        k = self.scales.get(_key(mutations))
        return {m.id: k for m in mutations if m.family == "scale" and k is not None}

    def _run(self, mutations: Sequence[Mutation], form: Form, scale: float) -> State | None:
        try:
            rerun = Rerun.with_mutations(self.noise, mutations, form, self.after, scale)
            with np.errstate(all="ignore"):  # a mutation may overflow: it reproduces nothing
                result = rerun.run(self.before, self.step)
        except RERUN_ERRORS:
            return None
        if not (np.isfinite(result.x).all() and np.isfinite(result.P).all()):
            return None
        return result

    def best(self, mutations: Sequence[Mutation], forms: Sequence[Form]) -> _Result:
        """Whether any of ``forms`` (only one covariance form unless the set changes the
        gain) reproduces the event with ``mutations``, else the nearest distance."""
        if not any(m.operation in _GAIN_OPERATIONS or m.id in _GAIN_MUTATIONS for m in mutations):
            forms = [f for f in forms if f.covariance == "ikh"] or list(forms)
        if any(m.operation in _BEARING_OPERATIONS for m in mutations):
            forms = [*forms, *(replace(f, wrap_h=False) for f in forms),
                     *(replace(f, wrap_h=False, wrap_heading=False) for f in forms)]  # fmt: skip
        if any(m.operation in _ASYMMETRIC_OPERATIONS for m in mutations):
            forms = [*forms, *(replace(f, symmetric=False) for f in forms)]
        nearest, state = math.inf, None
        for form in forms:
            result = self.run(mutations, form)
            if result is None:
                continue
            distance = scaled_distance(result, self.after)
            if distance <= self.close:
                return _Result(form, distance, result)
            if distance < nearest:
                nearest, state = distance, result
        return _Result(None, nearest, state)

    def relevance(
        self, origin: State, result: State, where: FloatArray | None = None
    ) -> tuple[float, float]:
        """How a re-run's change from ``origin`` compares with the filter's: the cosine of
        the two changes, and the length of what it leaves of the filter's (both scaled as
        the comparison scales its differences; over the entries ``where`` is 1 only)."""
        wanted, made = _change(origin, self.after), _change(origin, result)
        if wanted is None or made is None:
            return -1.0, math.inf
        if where is not None and len(where) == len(wanted) == len(made):
            wanted, made = wanted * where, made * where
        norms = float(np.linalg.norm(wanted) * np.linalg.norm(made))
        cosine = float(wanted @ made) / norms if norms > 0 else -1.0
        return cosine, float(np.linalg.norm(wanted - made))

    def first(self, mutations: Sequence[Mutation], forms: Sequence[Form]) -> Form | None:
        return self.best(mutations, forms).form

    def outside_reach(
        self, origin: State, base: list[Mutation], fitted: Mutation, form: Form
    ) -> FloatArray | None:
        """1 at the entries of x and P (as :func:`_change` lays them out) that no quantity
        ``fitted`` reads off can change, 0 at the others: those the scaled noise of its
        operation changes (its own noise reaches where a scale of the run's does); None
        where its operation has no such noise."""
        scaled = SCALED_OF.get(fitted.operation)
        if scaled is None:
            return None
        probe = self._run([*base, scaled], form, PROBE_SCALE)
        change = None if probe is None else _change(origin, probe)
        return None if change is None else (np.abs(change) <= 1e-12).astype(np.float64)

    def decides_mode(self) -> bool:
        """Whether the event tells the joint update from the sequential one: two known
        landmarks whose reference results differ."""
        if self._modes_differ is None:
            joint, sequential = self.run([], Form(True)), self.run([], Form(False))
            self._modes_differ = (
                joint is not None
                and sequential is not None
                and scaled_distance(joint, sequential) > self.close
            )
        return self._modes_differ


# each operation's scaled noise: what a quantity of that operation read off a filter reaches
SCALED_OF: dict[str, Mutation] = {m.operation: m for m in MUTATIONS if m.family == "scale"}


def _key(mutations: Sequence[Mutation]) -> tuple[str, ...]:
    return tuple(sorted(m.id for m in mutations))


def _change(origin: State, result: State) -> FloatArray | None:
    """``result - origin`` over x (the heading wrapped) and P, scaled as the comparison
    scales its differences; None where the landmarks differ."""
    if sorted(origin.ids.tolist()) != sorted(result.ids.tolist()):
        return None
    x, P = result.in_order_of(origin.ids)
    dx = x - origin.x
    dx[2] = wrap_angle(float(dx[2]))
    change = np.concatenate(
        [
            dx / np.maximum(1.0, np.abs(origin.x)),
            ((P - origin.P) / np.maximum(1.0, np.abs(origin.P))).ravel(),
        ]
    )
    return change if np.isfinite(change).all() else None


def scaled_distance(expected: State, got: State) -> float:
    """The largest |got - expected| / max(1, |expected|) over x (the heading's wrapped)
    and P, the landmarks matched by id; infinite where the ids differ."""
    if np.array_equal(expected.ids, got.ids):  # (the same order: nothing to gather)
        x, P = got.x, got.P
    elif sorted(expected.ids.tolist()) != sorted(got.ids.tolist()):
        return math.inf
    else:
        x, P = got.in_order_of(expected.ids)
    if x.shape != expected.x.shape:
        return math.inf
    dx = x - expected.x
    dx[2] = wrap_angle(float(dx[2]))
    worst_x = float(np.max(np.abs(dx) / np.maximum(1.0, np.abs(expected.x))))
    worst_P = float(np.max(np.abs(P - expected.P) / np.maximum(1.0, np.abs(expected.P))))
    return max(worst_x, worst_P)


def invalid(s: State) -> bool:
    """Whether a state is beyond what any run makes: a position beyond :data:`FAR`, P not
    positive definite to float64's precision (a negative eigenvalue, or one under
    :data:`SINGULAR` of the largest: the update of a P it made singular is round-off), or a
    variance far beyond the square of the state's extent."""
    if not (np.isfinite(s.x).all() and np.isfinite(s.P).all()):
        return True
    if float(np.max(np.abs(s.x[:2]))) > FAR or (len(s.x) > 3 and np.max(np.abs(s.x[3:])) > FAR):
        return True  # a filter that has lost its map: its floats no longer hold a metre
    extent = 1.0 + float(np.max(np.abs(s.x[:2]))) if len(s.x) else 1.0
    if len(s.x) > 3:
        extent = max(extent, 1.0 + float(np.max(np.abs(s.x[3:]))))
    if float(np.max(np.diag(s.P))) > INVALID_VARIANCE * extent * extent:
        return True
    eigenvalues = np.linalg.eigvalsh(0.5 * (s.P + s.P.T))
    return bool(eigenvalues[0] < SINGULAR * max(float(eigenvalues[-1]), 1e-300))


def _kind(step: Step) -> str:
    return "predict" if step.is_predict else "update"


def _minimal(trial: _Trial, base: Sequence[Mutation], form: Form) -> list[Mutation]:
    """``base`` without the mutations the event does not need."""
    kept = list(base)
    for mutation in sorted(base, key=lambda m: m.id):
        trying = [m for m in kept if m is not mutation]
        if trial.best(trying, [form]).form is not None:
            kept = trying
    return kept


def _refutes(
    noise: Noise,
    option: Sequence[Mutation],
    seen: Seen,
    tolerance: float,
    scales: dict[str, float],
    rivals: set[str],
) -> bool:
    """Whether ``option`` breaks the explanation of an earlier event (see
    :meth:`Diagnosis._unrefuted`); a scaled noise at the factor ``scales`` found for it
    (one factor a run: the code scales its noise alike at every event)."""
    acting = [m for m in option if acts_on(m, seen.step, seen.before)]
    if not acting or any(m.id in seen.explained_by for m in acting):
        return False
    explained = [MUTATION_BY_ID[c] for c in seen.explained_by if c in MUTATION_BY_ID]
    operations = {m.operation for m in acting}
    kept = [m for m in explained if m.operation not in operations and m.id not in rivals]
    mutations = kept + acting
    joint = any(c == "update_loop.joint" for c in seen.explained_by)
    trial = _Trial(noise, seen.before, seen.after, seen.step, max(tolerance * 10, 1e-8), scales,
                   fit=False)  # fmt: skip
    forms = [Form(joint, covariance) for covariance in ("ikh", "sks", "joseph")]
    return trial.best(mutations, forms).form is None


def _detail(chosen: Sequence[Mutation], trial: _Trial, form: Form) -> str:
    """What an ``own`` mutation read off the filter: its motion noise's sigmas."""
    if not any(m.id == "motion_noise.own" for m in chosen):
        return ""
    rerun = Rerun.with_mutations(trial.noise, chosen, form, trial.after)
    try:
        rerun.run(trial.before, trial.step)
        mutation = rerun.mutations["motion_noise"]
        Q = mutation.apply(rerun, lambda q: q, (trial.noise.Q,))
    except RERUN_ERRORS:
        return ""
    sigmas = np.sqrt(np.clip(np.diag(Q), 0.0, None))
    return (
        f"its motion sigmas are about {sigmas[0]:.4g}, {sigmas[1]:.4g}, {sigmas[2]:.4g}"
        " (along, sideways, turn)"
    )
