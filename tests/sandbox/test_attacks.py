"""The corpus of hostile submissions (:mod:`attacks`) graded beside an honest class and
judged by effects: a representative set of every kind together in one class by default,
each attack of the corpus alone under the ``slow`` marker (``pytest -m slow``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from attacks import ATTACKS, Verdict, baseline_of, run

# one of each kind, graded together in one class
REPRESENTATIVE = (
    "read_ancestors_environ", "read_the_log_graded", "link_to_neighbour", "wrap_the_reference",
    "fix_a_neighbour", "write_site_packages_pth", "write_to_ancestors_stdout",
    "escape_sequences_in_name", "formula_name_equals", "process_in_a_new_session",
    "kill_the_grader", "deep_folders_in_its_working_directory", "blank_lines",
    "sparse_gigabytes", "names_that_collide", "planted_link_in_save_dir",
    "send_over_loopback_tcp", "send_over_an_abstract_socket",
)  # fmt: skip


@pytest.fixture(scope="module")
def baseline(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, object]]:
    """The honest class's rows, graded alone."""
    return baseline_of(tmp_path_factory.mktemp("baseline"), sandbox=True)


def said(verdicts: list[Verdict]) -> str:
    return "\n".join(f"{v.attack}: {'; '.join(v.reasons)}" for v in verdicts if not v.clean)


def test_the_corpus_holds_every_kind_and_forty_attacks() -> None:
    kinds = {attack.kind for attack in ATTACKS}
    assert {"read", "write", "forge", "spoof", "outlive", "kill", "stall", "abort",
            "unbounded", "names", "network"} <= kinds  # fmt: skip
    assert len(ATTACKS) >= 40 and len({a.key for a in ATTACKS}) == len(ATTACKS)
    assert set(REPRESENTATIVE) <= {a.key for a in ATTACKS}


@pytest.mark.slow
def test_a_representative_set_graded_together_leaves_everything_clean(
    tmp_path: Path, baseline: dict[str, dict[str, object]]
) -> None:
    chosen = [attack for attack in ATTACKS if attack.key in REPRESENTATIVE]
    verdicts = run(chosen, tmp_path, baseline)
    assert all(verdict.clean for verdict in verdicts), said(verdicts)


@pytest.mark.slow
@pytest.mark.parametrize("key", [attack.key for attack in ATTACKS])
def test_each_attack_alone_leaves_everything_clean(
    tmp_path: Path, baseline: dict[str, dict[str, object]], key: str
) -> None:
    (verdict,) = run([a for a in ATTACKS if a.key == key], tmp_path, baseline)
    assert verdict.clean, said([verdict])
