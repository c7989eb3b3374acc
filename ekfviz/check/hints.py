"""What ``check`` tells a user of a divergent event: the causes named (what the code does,
the fix, the line of their file that computes it), or, where nothing reproduces the
event, the first operation that differs and its numbers."""

from __future__ import annotations

from dataclasses import dataclass

from ekfviz.check.mistakes import cause
from ekfviz.check.search import Finding
from ekfviz.check.source import Quoted, Source
from ekfviz.check.unknown import Unexplained

HANDOUT_NOTE = (
    "a course module's P starts as the handout's main() builds it, block_diag(pose_cov,"
    " landmark_cov), so every one shows this; init_cross_covariance in the module (README)"
    " fills in the cross-covariances"
)
PRIOR_HINT = (
    "the filter does not start from the prior: x = init_pose, P = diag(init_pose_sigma^2)"
    " (FilterParams.init_pose, init_pose_sigma)"
)
IDS_HINT = (
    "the filter's landmark_ids differ from the observed landmarks: every id of an update"
    " must be in the state afterwards, new ones appended in the order seen"
)


@dataclass(frozen=True, slots=True)
class Named:
    """One cause named at a divergence, as its report gives it.

    :param sentence: what the code does; ``fix`` how to fix it
    :param source: the line of the submitted file that computes the operation, if found
    """

    id: str
    operation: str
    mutation: str
    family: str
    sentence: str
    fix: str
    aliases: tuple[str, ...] = ()
    source: Quoted | None = None

    def hint(self, file_name: str) -> str:
        text = f"{self.sentence}; fix: {self.fix}"
        if self.source is not None:
            where = f" in {self.source.function}" if self.source.function else ""
            text += f" (at {file_name}:{self.source.line}{where}: {self.source.text})"
        return text

    def to_json(self) -> dict[str, object]:
        return {
            "id": self.id,
            "operation": self.operation,
            "mutation": self.mutation,
            "family": self.family,
            "sentence": self.sentence,
            "fix": self.fix,
            "aliases": list(self.aliases),
            "source": None if self.source is None else self.source.to_json(),
        }


def named(
    causes: tuple[str, ...], source: Source | None, scales: tuple[tuple[str, float], ...] = ()
) -> tuple[Named, ...]:
    """The causes of a finding, each with its line in ``source`` where found; a scaled
    noise's sentence with the factor of ``scales`` (cause id, k) read off the filter."""
    from ekfviz.check.mutations import MUTATION

    factors = dict(scales)
    found = []
    for cause_id in causes:
        entry = cause(cause_id)
        mutation = MUTATION[entry.id]
        quoted = None if source is None else source.quote(mutation)
        sentence = entry.wrong
        if mutation.says is not None and entry.id in factors:
            sentence = mutation.says(factors[entry.id])
        found.append(Named(entry.id, entry.operation, entry.mutation, entry.family,
                           sentence, entry.fix, entry.aliases, quoted))  # fmt: skip
    return tuple(found)


def hint(
    finding: Finding,
    causes: tuple[Named, ...],
    unexplained: Unexplained | None,
    file_name: str,
    fallback: str,
) -> str:
    """The hint of one divergent event (see the module)."""
    if finding.inherited:
        listed = ", ".join(finding.causes)
        return (
            f"the doing of {listed}, found at an earlier event: the state before this one"
            " is already invalid or ill-conditioned from it (P not positive semi-definite,"
            " variances far beyond any the log makes, or an S near singular), and those"
            " mistakes explain this event but for its round-off; fix them first"
        )
    if finding.alternatives:
        options = " OR ".join("+".join(option) for option in finding.alternatives)
        return (
            f"this event is reproduced equally by {options}: neither it nor the rest of the"
            " log tells them apart (check --all, or a log that exercises more, may)"
        )
    if causes:
        text = " AND ".join(named_cause.hint(file_name) for named_cause in causes)
        if finding.detail:
            text += f" ({finding.detail})"
        if finding.indistinct:
            others = " OR ".join("+".join(option) for option in finding.indistinct)
            text += f" (this log cannot tell it from {others})"
        return text
    if unexplained is not None:
        return unexplained.sentence()
    return fallback
