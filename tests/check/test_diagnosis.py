"""check's diagnosis: the catalogue of mutations, the search that names them, the lines it
quotes, the noise a filter declares, and the corpus of course modules it is measured on
(a few of it by default; the whole of it under ``-m slow``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import corpus
import numpy as np
import pytest
import students
from conftest import few_by_default

from ekfviz.check.mistakes import catalogue, table, table_in
from ekfviz.check.mutations import ALIASES, MUTATION, MUTATIONS, resolve
from ekfviz.check.operations import OPERATION
from ekfviz.check.probes import acts_on, fingerprint, is_inert
from ekfviz.check.rerun import RERUN_ERRORS, Form, Noise, Rerun, State, Step
from ekfviz.check.search import Diagnosis, scaled_distance
from ekfviz.check.source import Source
from ekfviz.core.params import FilterParams

ROOT = Path(__file__).resolve().parents[2]
NOISE = Noise(FilterParams().Q, FilterParams().R)


# -- the catalogue ---------------------------------------------------------------------------


def test_the_readme_holds_the_catalogue_as_generated() -> None:
    """The documentation's table is what ``python -m ekfviz.check.mistakes docs/causes.md``
    writes."""
    assert table_in(ROOT / "docs" / "causes.md") == table()


def test_every_earlier_id_resolves_to_a_cause_of_the_catalogue() -> None:
    listed = {cause.id for cause in catalogue()}
    for old, new in ALIASES.items():
        assert new in MUTATION, old
        assert resolve(old) == new and resolve(new) == new
        assert new in listed, (old, new)  # none is an equal of another, nor inert


def test_every_mutation_is_of_an_operation_and_a_family() -> None:
    from ekfviz.check.mutations import FAMILIES

    ids = [m.id for m in MUTATIONS]
    assert len(ids) == len(set(ids))
    for mutation in MUTATIONS:
        assert mutation.operation in OPERATION and mutation.family in FAMILIES
        assert mutation.wrong and mutation.fix


def test_the_mutations_the_search_leaves_out_change_no_event() -> None:
    from ekfviz.check.mutations import INERT

    assert {m.id for m in MUTATIONS if is_inert(m.id)} == INERT


def test_mutations_no_event_tells_apart_are_one_cause() -> None:
    """The innovation's sign and the correction's change every event alike; a sign of a
    column of J_z changes none (R is diagonal); two signs of G's heading column differ
    wherever the heading is not 0."""
    assert fingerprint("innovation.sign") == fingerprint("corrected_mean.sign")
    assert is_inert("init_jacobian_measurement.sign_column_bearing")
    assert not is_inert("innovation.not_wrapped")
    assert fingerprint("motion_jacobian.sign_column_theta") != fingerprint(
        "motion_jacobian.sign_y_theta"
    )
    causes = {cause.id: cause for cause in catalogue()}
    assert "corrected_mean.sign" in causes["innovation.sign"].same_as
    assert "init_jacobian_measurement.sign_column_bearing" not in causes


# -- the search on generated events ----------------------------------------------------------


def _state(seed: int) -> State:
    rng = np.random.default_rng(seed)
    pose = np.array([1.0, 2.0, 0.7])
    directions = 0.7 + np.array([0.5, 3.1, -1.0, -2.4, 1.8])
    ranges = np.array([5.0, 6.0, 7.0, 4.5, 8.0])
    landmarks = pose[:2] + ranges[:, None] * np.column_stack([np.cos(directions),
                                                               np.sin(directions)])  # fmt: skip
    x = np.concatenate([pose, landmarks.ravel()])
    A = rng.normal(size=(len(x), len(x)))
    return State(x, A @ A.T / len(x) * 0.02 + 0.01 * np.eye(len(x)), np.arange(1, 6))


def _events(s: State) -> list[tuple[State, Step]]:
    rng = np.random.default_rng(5)
    bearings = np.array([0.5, 3.1, -1.0, -2.4, 1.8]) + rng.normal(0, 0.03, 5)
    z = np.column_stack([bearings, np.array([5.0, 6.0, 7.0, 4.5, 8.0]) + rng.normal(0, 0.1, 5)])
    z[:, 0] = (z[:, 0] + np.pi) % (2 * np.pi) - np.pi
    empty = State(s.x[:3].copy(), s.P[:3, :3].copy(), np.zeros(0, dtype=np.int64))
    mixed = np.vstack([z[1], [0.4, 3.0], z[3], [-2.0, 5.0]])
    first = np.array([[0.5, 5], [-2.8, 4], [2, 7]])
    return [(s, Step(d=1.2, alpha=0.3)), (s, Step(d=0.0, alpha=0.0)),
            (s, Step(ids=s.ids, z=z)), (s, Step(ids=np.array([2, 9, 4, 10]), z=mixed)),
            (empty, Step(ids=np.array([1, 2, 3]), z=first))]  # fmt: skip


def _named_from_its_own_result(mutation_id: str) -> bool:
    """Whether the search, given what ``mutation_id`` makes of the first event it changes,
    names it (or a mutation no event tells from it) alone."""
    mutation = MUTATION[mutation_id]
    for before, step in _events(_state(11)):
        if not acts_on(mutation, step, before):
            continue
        try:  # (a mutation that cannot run on this event, as the search takes it: not here)
            target = Rerun.with_mutations(NOISE, [mutation], Form(), None).run(before, step)
        except RERUN_ERRORS:
            continue
        if scaled_distance(Rerun(NOISE).run(before, step), target) < 1e-9:
            continue
        found = Diagnosis(NOISE, Form(), 1e-6).explain(before, target, step)
        named = found.causes and len(found.causes) == 1
        return bool(named and fingerprint(found.causes[0]) == fingerprint(mutation_id)) or any(
            len(option) == 1 and fingerprint(option[0]) == fingerprint(mutation_id)
            for option in found.indistinct
        )
    return True  # it changes none of these events: the probes' coverage says so elsewhere


SEARCHED = [m.id for m in MUTATIONS if m.family not in ("own", "form")]


@pytest.mark.parametrize("mutation_id", SEARCHED[::12])
def test_a_mutation_is_named_from_what_it_does(mutation_id: str) -> None:
    assert _named_from_its_own_result(mutation_id)


@pytest.mark.slow
@pytest.mark.parametrize("mutation_id", [m for k, m in enumerate(SEARCHED) if k % 12])
def test_every_mutation_is_named_from_what_it_does(mutation_id: str) -> None:
    assert _named_from_its_own_result(mutation_id)


@pytest.mark.slow
def test_two_and_three_mistakes_at_once_are_named_together() -> None:
    s = _state(3)
    before, step = _events(s)[2]
    for ids in (("innovation_covariance.noise_twice", "corrected_covariance.joseph_without_noise"),
                ("expected_measurement.atan2_swapped", "update_loop.stale_linearisation",
                 "kalman_gain.inverse_missing")):  # fmt: skip
        target = Rerun.with_mutations(NOISE, [MUTATION[i] for i in ids], Form(), None).run(
            before, step
        )
        found = Diagnosis(NOISE, Form(), 1e-6).explain(before, target, step)
        assert sorted(found.causes) == sorted(ids)


def test_a_tie_is_refuted_by_the_events_the_filter_got_right() -> None:
    """At a standstill, no noise at all, none when not driving and none when standing
    still do the same; the predicts the filter got right (driving, turning on the spot)
    refute the first two."""
    from ekfviz.check.search import Seen

    s = _state(4)
    still = Step(d=0.0, alpha=0.0)
    history = [Seen(step, s, Rerun(NOISE).run(s, step))
               for step in (Step(d=1.2, alpha=0.3), Step(d=0.0, alpha=0.3))]  # fmt: skip
    mutation = MUTATION["motion_noise.missing_when_still"]
    target = Rerun.with_mutations(NOISE, [mutation], Form(), None).run(s, still)
    diagnosis = Diagnosis(NOISE, Form(), 1e-6)
    assert diagnosis.explain(s, target, still, history=history[:1]).indistinct
    found = Diagnosis(NOISE, Form(), 1e-6).explain(s, target, still, history=history)
    assert found.causes == ("motion_noise.missing_when_still",) and not found.indistinct


# -- the line a hint quotes --------------------------------------------------------------------


def test_the_line_of_the_submitted_file_that_computes_the_operation() -> None:
    source = Source(corpus.SKELETON_TEXT, "ekf_slam.py")
    lines = corpus.SKELETON_TEXT.splitlines()
    for cause, text in (
        ("innovation_covariance.noise_missing", "S = H @ P @ H.T + measure_cov"),
        ("kalman_gain.inverse_elementwise", "K = np.linalg.solve(S, H @ P).T"),
        ("expected_measurement.atan2_swapped", "innovation = measure[2 * i : 2 * i + 2, 0]"),
        ("motion_jacobian.sign_column_theta", "G = np.eye(3 + 2 * k)"),
        ("update_loop.one_short", "for i in range(k):"),
    ):
        quoted = source.quote(MUTATION[cause])
        assert quoted is not None, cause
        assert quoted.text.startswith(text), (cause, quoted)
        assert lines[quoted.line - 1].strip() == quoted.text
        assert quoted.function in ("predict", "update")


def test_a_hint_quotes_the_students_line_and_the_report_carries_it(tmp_path: Path) -> None:
    path = tmp_path / "ekf_slam.py"
    path.write_text(corpus.apply(corpus.SOLUTION_TEXT, corpus.MISTAKES["no_r"].edits["solution"]))
    from ekfviz.check.lockstep import lockstep
    from ekfviz.core.records import with_ids
    from ekfviz.filters.spec import FilterSpec
    from ekfviz.sources import read_log

    make_filter = FilterSpec(str(path)).load()
    try:
        result = lockstep(with_ids(read_log(ROOT / "data" / "classic.txt")), FilterParams(),
                          make_filter, name=str(path))  # fmt: skip
    finally:
        make_filter.close()  # type: ignore[attr-defined]
    following = result.next_divergence
    assert following is not None and following.cause == "innovation_covariance.noise_missing"
    number = path.read_text().splitlines().index("        S = H @ P @ H.T") + 1
    assert f"(at ekf_slam.py:{number} in update: S = H @ P @ H.T)" in following.hint
    document: dict[str, Any] = following.to_json()
    assert document["operation"] == "innovation_covariance"
    assert document["mutation"] == "noise_missing"
    assert document["source"] == {"line": number, "function": "update", "text": "S = H @ P @ H.T"}
    assert document["sentence"].startswith("R is missing from the innovation covariance")
    assert document["causes"][0]["fix"] == "S = H P H^T + R"
    assert document["causes"][0]["aliases"] == ["missing_measurement_noise"]
    json.dumps(document)


# -- the noise a filter declares ---------------------------------------------------------------


class _Declares:
    """The textbook filter, declaring the sigmas as its motion noise's variances."""

    def __init__(self, params: Any) -> None:
        from plugins.textbook import Textbook

        self.inner = Textbook(params)
        self.motion_noise = np.diag([params.sigma_x, params.sigma_y, params.sigma_alpha])

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def predict(self, d: float, alpha: float) -> None:
        self.inner.Q = self.motion_noise  # it uses what it declares
        self.inner.predict(d, alpha)


def test_declared_noise_is_compared_named_and_never_adopted() -> None:
    from ekfviz.check.lockstep import lockstep
    from ekfviz.core.records import with_ids
    from ekfviz.sources import read_log

    result = lockstep(with_ids(read_log(ROOT / "data" / "classic.txt")), FilterParams(),
                      _Declares, name="declares", every=True)  # fmt: skip
    first = result.first_divergence
    assert first is not None and first.event == 0 and first.cause == "motion_noise.sigmas"
    assert first.worst.quantity.value == "declared noise"
    assert any("declares motion_noise" in note for note in result.notes)
    # the reference kept the run's Q: every predict diverges, and is the same cause's
    predicts = [d for d in result.divergences if d.kind.value == "predict"]
    assert len(predicts) == 29 and {d.cause for d in predicts} == {"motion_noise.sigmas"}
    assert result.causes == ["motion_noise.sigmas"]


# -- the corpus ----------------------------------------------------------------------------------

FAST_MUTANTS = ["skeleton/no_r", "solution/s_inverse_elementwise", "skeleton/still_no_noise",
                "solution/dx_reversed"]  # fmt: skip
FAST_CORRECT = ["flat_but_column_pose_at_init", "float32", "class_with_the_handouts_init",
                "np_matrix"]  # fmt: skip
MUTANTS = {name: (cause, text) for name, cause, text in corpus.mutants()}


def _mutant_is_named_exactly(tmp_path: Path, name: str) -> None:
    cause, text = MUTANTS[name]
    path = tmp_path / "ekf_slam.py"
    path.write_text(text)
    found = corpus.verdict(path)
    assert found.mistakes == {cause}, found
    assert not found.unknown, found  # (the module itself may fail later: a P it broke)
    assert found.others <= {corpus.HANDOUT}


def _correct_passes(tmp_path: Path, name: str) -> None:
    path = tmp_path / "ekf_slam.py"
    path.write_text(corpus.CORRECT[name])
    found = corpus.verdict(path)
    assert not found.mistakes and not found.unknown and not found.errors, found
    assert all(MUTATION[c].family in ("handout", "form") for c in found.others)


@pytest.mark.parametrize("name", few_by_default(FAST_MUTANTS, 2))
def test_a_students_mistake_is_named_exactly(tmp_path: Path, name: str) -> None:
    _mutant_is_named_exactly(tmp_path, name)


@pytest.mark.parametrize("name", few_by_default(FAST_CORRECT, 2))
def test_correct_code_written_unusually_passes(tmp_path: Path, name: str) -> None:
    _correct_passes(tmp_path, name)


def test_a_float32_filter_is_held_to_its_precision_and_told_so(tmp_path: Path) -> None:
    from ekfviz.check.lockstep import lockstep
    from ekfviz.core.records import with_ids
    from ekfviz.filters.spec import FilterSpec
    from ekfviz.sources import read_log

    path = tmp_path / "ekf_slam.py"
    path.write_text(corpus.CORRECT["float32"])
    make_filter = FilterSpec(str(path)).load()
    try:
        result = lockstep(with_ids(read_log(ROOT / "data" / "classic.txt")), FilterParams(),
                          make_filter, name=str(path))  # fmt: skip
    finally:
        make_filter.close()  # type: ignore[attr-defined]
    assert result.precision == "float32" and result.tolerance == 1e-4
    assert result.first_divergence is None and 1e-6 < result.within_precision < 1e-4
    said = " ".join(str(line) for line in result.verdict_lines("classic", every=False))
    assert "the filter computes in float32" in said and "its precision's" in said


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(MUTANTS) - set(FAST_MUTANTS) - set(corpus.UNTELLABLE)))
def test_every_mutant_of_the_corpus(tmp_path: Path, name: str) -> None:
    _mutant_is_named_exactly(tmp_path, name)


@pytest.mark.parametrize("name", sorted(corpus.UNTELLABLE))
def test_a_mistake_no_output_shows_is_not_named_and_gives_the_correct_output(
    tmp_path: Path, name: str
) -> None:
    """The solution's J_p with its heading column negated: with the handout's init (no
    P_lx) and a diagonal pose covariance at initialisation, P_ll = J_p P_rr J_p^T is the
    same whatever that column's sign; check names what the correct solution gets."""
    path = tmp_path / "ekf_slam.py"
    path.write_text(MUTANTS[name][1])
    found = corpus.verdict(path)
    correct = tmp_path / "correct" / "ekf_slam.py"  # (the hints quote the file's name)
    correct.parent.mkdir()
    correct.write_text(corpus.STYLES[corpus.UNTELLABLE[name]])
    assert found == corpus.verdict(correct)
    assert not found.mistakes and not found.unknown and found.others == {corpus.HANDOUT}
    # the same mutation is told where the pose is correlated at the initialisation
    mutation, handout = MUTATION[MUTANTS[name][0]], MUTATION[corpus.HANDOUT]
    s = _state(8)
    empty, step = _events(s)[-1][0], _events(s)[-1][1]
    for P_rr, told in ((np.diag([0.01, 0.02, 0.03]), False), (s.P[:3, :3], True)):
        before = State(empty.x, P_rr, empty.ids)
        alone = Rerun.with_mutations(NOISE, [handout], Form(), None).run(before, step)
        both = Rerun.with_mutations(NOISE, [handout, mutation], Form(), None).run(before, step)
        assert (scaled_distance(alone, both) > 1e-6) == told


# -- the families whose quantity the search reads off the filter --------------------------------

FAST_FAMILY = ["scaled/skeleton_r_in_s", "own_noise/textbook_g_heading_sign",
               "jp_sign/class_of_the_skeleton"]  # fmt: skip


def _family_mutant_is_named_exactly(tmp_path: Path, name: str) -> None:
    mutant = corpus.FAMILY_MUTANTS[name]
    path = tmp_path / "ekf_slam.py"
    path.write_text(mutant.text)
    found = corpus.verdict(path, spec=mutant.spec)
    assert found.mistakes == mutant.causes, found
    assert not found.unknown and not found.errors, found
    assert found.others <= {corpus.HANDOUT}


@pytest.mark.parametrize("name", few_by_default(FAST_FAMILY, 1))
def test_a_family_mutant_is_named_exactly(tmp_path: Path, name: str) -> None:
    _family_mutant_is_named_exactly(tmp_path, name)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(corpus.FAMILY_MUTANTS) - set(FAST_FAMILY)))
def test_every_family_mutant(tmp_path: Path, name: str) -> None:
    _family_mutant_is_named_exactly(tmp_path, name)


def test_the_family_mutants_come_in_several_shapes_each() -> None:
    families: dict[str, set[str]] = {}
    for name, mutant in corpus.FAMILY_MUTANTS.items():
        families.setdefault(name.split("/")[0], set()).add(mutant.text)
    assert set(families) == {"scaled", "own_noise", "jp_sign"}
    assert all(len(texts) >= 3 for texts in families.values())


SCALED = [m.id for m in MUTATIONS if m.family == "scale"]


@pytest.mark.parametrize("mutation_id", SCALED)
def test_a_scaled_noise_is_named_with_its_factor(mutation_id: str) -> None:
    """Each scaled noise at factors either way of 1: named alone, or as a mutation no
    event tells from it (Q scaled and W Q W^T scaled), or among those this event cannot
    tell from it (R scaled everywhere and in S alike, at an update with no new landmark);
    its factor read back to 1e-3 (a small R moves S little)."""
    mutation = MUTATION[mutation_id]
    for k in (0.1, 0.4, 3.0, 25.0):
        for before, step in _events(_state(13)):
            if not acts_on(mutation, step, before):
                continue
            target = Rerun.with_mutations(NOISE, [mutation], Form(), None, k).run(before, step)
            found = Diagnosis(NOISE, Form(), 1e-6).explain(before, target, step)
            assert len(found.causes) == 1, (k, step, found)
            options = [found.causes, *found.indistinct]
            assert any(len(option) == 1 and fingerprint(option[0]) == fingerprint(mutation_id)
                       for option in options), (k, found)  # fmt: skip
            (cause, factor), *_ = found.scales
            assert cause == found.causes[0] and factor == pytest.approx(k, rel=1e-3)
            break


def test_a_scaled_noise_is_said_with_its_factor(tmp_path: Path) -> None:
    path = tmp_path / "ekf_slam.py"
    path.write_text(corpus.FAMILY_MUTANTS["scaled/skeleton_r_in_s"].text)
    hints = corpus.verdict(path).hints
    said = "R is used 10 times too large in S: S = H P H^T + 10 R; fix: S = H P H^T + R"
    assert any(hint.startswith(said) for hint in hints), hints
    path.write_text(corpus.FAMILY_MUTANTS["scaled/flat_q_halved"].text)
    said = "Q is used 2 times too small in the predicted covariance"
    assert any(hint.startswith(said) for hint in corpus.verdict(path).hints)


def test_a_filter_class_with_a_noise_of_its_own_gets_its_predicts_named() -> None:
    """The open-source style filter declares no noise: its own (0.5 m, 0.5 m, 30 degrees,
    in the world frame) completes G transposed and the cross-covariances not propagated;
    its updates (S with a noise of its own, a landmark updated with its first
    measurement) stay unknown."""
    from ekfviz.check.lockstep import lockstep
    from ekfviz.core.records import with_ids
    from ekfviz.filters.spec import load_in_process
    from ekfviz.sources import read_log

    plugin = str(ROOT / "tests" / "plugins" / "robotics_style.py") + ":RoboticsStyle"
    result = lockstep(with_ids(read_log(ROOT / "data" / "classic.txt")), FilterParams(),
                      load_in_process(plugin), name="robotics", every=True)  # fmt: skip
    predicts = [g for g in result.groups if g.kind == "predict"]
    assert predicts and {g.cause for g in predicts} == {
        "motion_jacobian.transposed+cross_covariance.skipped+motion_noise.own"
    }
    assert "its motion sigmas are about 0.5, 0.5, 0.5236" in predicts[0].first.hint
    assert {g.kind for g in result.groups if g.cause == "unknown"} <= {"init", "update"}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(corpus.CORRECT) - set(FAST_CORRECT)))
def test_every_correct_module_of_the_corpus(tmp_path: Path, name: str) -> None:
    _correct_passes(tmp_path, name)


def test_the_corpus_holds_both_styles_and_enough_of_each() -> None:
    styles = {name.split("/")[0] for name in MUTANTS}
    assert styles == {"skeleton", "solution"}
    assert len(MUTANTS) >= 60 and len(corpus.CORRECT) >= 20
    assert set(students.STUDENTS) <= set(students.MISTAKES)


# -- the battery and what a log cannot tell apart ------------------------------------------------


def test_what_each_log_of_the_battery_cannot_tell_apart() -> None:
    """The classic log never stands still (no noise at a standstill passes it), the edge log
    does; neither tells a landmark placed before the line's corrections (every landmark
    is new on the first line only), the mid-run log does."""
    from ekfviz.check.coverage import untellable
    from ekfviz.core.records import with_ids
    from ekfviz.sim.scenarios import EDGE_START
    from ekfviz.sources import read_log

    def untold(log: str, params: FilterParams) -> set[str]:
        events = list(with_ids(read_log(ROOT / "data" / f"{log}.txt")))
        return {item.untested.rsplit("(", 1)[1] for item in untellable(events, params)}

    classic = untold("classic", FilterParams())
    assert any("motion_noise.missing_when_still" in said for said in classic)
    assert any("init_pose.before_line" in said for said in classic)
    edge = untold("edge", FilterParams(init_pose=EDGE_START))
    assert not any("motion_noise.missing_when" in said for said in edge)
    assert not any("innovation.not_wrapped" in said for said in edge)
    # (the noise the mid-run log's header states)
    midrun = untold("midrun", FilterParams(sigma_x=0.124907, sigma_y=0.062453,
                                           sigma_alpha=0.012491))  # fmt: skip
    assert not any("init_pose.before_line" in said for said in midrun)


def test_a_course_module_is_not_run_on_the_mid_run_log_and_says_why() -> None:
    from ekfviz.check.lockstep import course_cannot_read
    from ekfviz.core.records import with_ids
    from ekfviz.sources import read_log

    events = list(with_ids(read_log(ROOT / "data" / "midrun.txt")))
    why = course_cannot_read(events)
    assert why.startswith("a course module cannot read this log: its line")
    assert "init_landmarks is called once, on the first line" in why
    assert course_cannot_read(list(with_ids(read_log(ROOT / "data" / "classic.txt")))) == ""


def test_a_filter_class_is_checked_on_the_mid_run_log() -> None:
    from ekfviz.check.lockstep import lockstep
    from ekfviz.core.records import with_ids
    from ekfviz.filters.spec import load_in_process
    from ekfviz.sources import read_log

    plugin = str(ROOT / "tests" / "plugins" / "textbook.py") + ":Textbook"
    params = FilterParams(sigma_x=0.124907, sigma_y=0.062453, sigma_alpha=0.012491,
                          init_pose_sigma=(0.01, 0.01, 0.005))  # fmt: skip
    result = lockstep(with_ids(read_log(ROOT / "data" / "midrun.txt")), params,
                      load_in_process(plugin), name="textbook")  # fmt: skip
    assert result.match, result.first_divergence
    assert result.events_checked == 49
