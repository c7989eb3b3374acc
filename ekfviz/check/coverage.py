"""What a log exercises of a filter's branches, so that a ``check`` match means something.

A filter that never wraps its bearing innovation matches the reference on every log
whose bearings stay away from +-pi; one that mishandles a heading across +-pi matches
while the heading stays in (-pi/2, pi/2). :func:`coverage` says which of these a log
(and the path the reference follows on it) did and did not exercise; and, for each
operation, which families of mutations of it no event of the log tells from correct
code (:func:`untellable`): each mutation is re-run at the events it acts on, from the
reference's own states along the log, until one changes the result.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ekfviz.check.rerun import RERUN_ERRORS, Form, Noise, Rerun, State, Step
from ekfviz.core.params import FilterParams, UpdateMode
from ekfviz.core.records import Control, EventRecord, LogEvent, Sighting

NEAR_PI = 0.1  # rad: a bearing or heading this close to +-pi exercises angle wrapping


@dataclass(frozen=True, slots=True)
class Item:
    """One branch: its id, whether the log exercised it, and what that means when not."""

    id: str
    exercised: bool
    untested: str

    def to_json(self) -> dict[str, object]:
        return {"id": self.id, "exercised": self.exercised, "untested": self.untested}


def coverage(
    events: Iterable[LogEvent],
    records: Iterable[EventRecord],
    params: FilterParams,
    *,
    operations: bool = False,
) -> list[Item]:
    """The branches the log's events (and the poses of ``records``) exercised; with
    ``operations``, then each operation whose mutations of some family the log cannot
    tell from correct code (:func:`untellable`)."""
    events = list(events)
    items = _branches(events, records, params)
    if operations:
        items += untellable(events, params)
    return items


def _branches(
    events: Iterable[LogEvent], records: Iterable[EventRecord], params: FilterParams
) -> list[Item]:
    """The branches the log's events (and the poses of ``records``) exercised."""
    near_pi = behind = crossing = several = mid_run = big_turn = backwards = False
    last_bearing: dict[int, float] = {}
    seen: set[int] = set()
    first = True
    for event in events:
        if isinstance(event, Control):
            big_turn |= abs(event.alpha) > math.pi / 2
            backwards |= event.d < 0
        elif isinstance(event, Sighting):
            ids = [int(i) for i in event.ids]
            several |= len(ids) > 1
            if not first and any(i not in seen for i in ids):
                mid_run = True
            for landmark_id, (bearing, _) in zip(ids, event.z.tolist(), strict=True):
                near = abs(bearing) > math.pi - NEAR_PI
                near_pi |= near
                behind |= abs(bearing) > math.pi / 2
                previous = last_bearing.get(landmark_id)
                if near and previous is not None and previous * bearing < 0:
                    crossing |= abs(previous) > math.pi / 2
                last_bearing[landmark_id] = bearing
            seen.update(ids)
        first = False
    headings = [float(r.pose[2]) for r in records]
    heading_near_pi = any(abs(h) > math.pi - NEAR_PI for h in headings)
    heading_crosses = any(
        a * b < 0 and abs(a) > math.pi / 2 and abs(b) > math.pi / 2
        for a, b in itertools.pairwise(headings)
    )
    off_origin = any(abs(v) > 1e-9 for v in params.init_pose)
    return [
        Item("bearing_near_pi", near_pi, f"no bearing within {NEAR_PI:g} rad of +-pi: the"
             " wrapping of the bearing innovation is untested"),
        Item("bearing_crosses_pi", crossing, "no landmark's bearing changes sign across"
             " +-pi between sightings: an innovation of about 2 pi never arises"),
        Item("landmark_behind", behind, "no landmark is seen behind the robot (|bearing| >"
             " pi/2)"),
        Item("heading_near_pi", heading_near_pi, "the heading never comes within"
             f" {NEAR_PI:g} rad of +-pi: wrapping the heading is untested"),
        Item("heading_crosses_pi", heading_crosses, "the heading never crosses +-pi"),
        Item("turn_over_half_pi", big_turn, "no control turns by more than pi/2"),
        Item("start_off_origin", off_origin, "the start is the origin: a filter that"
             " ignores the initial pose passes"),
        Item("several_landmarks_per_update", several, "no update sees two landmarks:"
             " joint and sequential updates cannot differ"),
        Item("new_landmark_mid_run", mid_run, "every landmark is seen first on the first"
             " line: initialisation inside a later update is untested"),
        Item("driving_backwards", backwards, "no control drives backwards (d < 0)"),
    ]  # fmt: skip


def untested(items: Sequence[Item]) -> list[Item]:
    return [item for item in items if not item.exercised]


# the events of a log its mutations are re-run at (the first ones), and the largest state
MAX_EVENTS = 400
MAX_DIM = 200


def untellable(events: Sequence[LogEvent], params: FilterParams) -> list[Item]:
    """For each operation, the families of its mutations no event of the log tells from
    correct code (each mutation re-run at every event it acts on, from the reference's
    own state before it, until one changes the result by more than round-off)."""
    from ekfviz.check.mutations import FAMILIES, INERT, MUTATIONS
    from ekfviz.check.operations import OPERATION
    from ekfviz.check.probes import acts_on
    from ekfviz.check.search import scaled_distance

    noise = Noise(params.Q, params.R)
    joint = Form(params.update is UpdateMode.JOINT)
    walk = _reference_walk(events, params, noise, joint)
    untold: dict[tuple[str, str], list[str]] = {}
    for mutation in MUTATIONS:
        if mutation.family in ("own", "form") or mutation.id in INERT:
            continue
        told = False
        for before, step, after in walk:
            if not acts_on(mutation, step, before):
                continue
            try:
                result = Rerun.with_mutations(noise, [mutation], joint, None).run(before, step)
            except RERUN_ERRORS:
                told = True
                break
            if scaled_distance(after, result) > 1e-9:
                told = True
                break
        if not told:
            untold.setdefault((mutation.operation, mutation.family), []).append(mutation.id)
    items = []
    for (operation, family), ids in untold.items():
        listed = ", ".join(ids[:3]) + (", ..." if len(ids) > 3 else "")
        items.append(Item(
            f"mutation:{operation}.{family}", False,
            f"{OPERATION[operation].title}: {FAMILIES[family]} cannot be told from correct"
            f" code on this log ({listed})",
        ))  # fmt: skip
    return items


def _reference_walk(
    events: Sequence[LogEvent], params: FilterParams, noise: Noise, form: Form
) -> list[tuple[State, Step, State]]:
    """The reference's own run over the first :data:`MAX_EVENTS` events (while its state
    has at most :data:`MAX_DIM` entries): each event with the state before and after it."""
    from ekfviz.check.lockstep import step_of
    from ekfviz.models.kalman import prior_covariance

    pose = np.array(params.init_pose, dtype=np.float64)
    state = State(pose, prior_covariance(params.init_pose_sigma), np.zeros(0, dtype=np.int64))
    walk = []
    for event in events[:MAX_EVENTS]:
        if not isinstance(event, Control | Sighting) or len(state.x) > MAX_DIM:
            break
        step = step_of(event)
        try:
            after = Rerun(noise, form=form).run(state, step)
        except RERUN_ERRORS:
            break
        walk.append((state, step, after))
        state = after
    return walk
