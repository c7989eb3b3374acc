"""The map's legend: what each colour and mark means, for the entities a run drew.

A markdown document (``run/legend``) shown in a strip beneath the map: the viewer's 2-D
view has no legend of its own, and blue, grey, magenta, red and green could only be
told apart by hovering.
"""

from __future__ import annotations

from collections.abc import Collection

import rerun as rr

from ekfviz.viz import style

# The association's and the GPS reference's map entities (spelled out: their module,
# ekfviz.viz.association, imports the recorder, which imports this one)
ASSOCIATION_RAYS = "world/association/rays"
ASSOCIATION_TENTATIVE = "world/landmarks/tentative"
GPS_TRACK = "world/reference/gps"

# The entity paths (the first with data decides) and what they draw, in the legend's order.
ENTRIES: tuple[tuple[tuple[str, ...], str], ...] = (
    ((style.ROBOT,), "**black dot and line**: the robot and its heading"),
    ((style.TRAJECTORY,), "**blue line**: the estimated path"),
    ((style.POSE_UPDATED,), "**blue ellipse**: the pose's 3σ after the update"),
    ((style.POSE_PREDICTED,), "**magenta ellipse**: the pose's 3σ after the predict"),
    (
        (style.LANDMARKS,),
        "**green dots and ellipses**: the landmarks and their 3σ now (L<id>)",
    ),
    ((style.LANDMARK_INITIAL,), "**red ellipse**: a landmark's 3σ when it was first seen"),
    ((style.OBSERVATIONS,), "**orange rays**: the measurements at the cursor"),
    (
        (ASSOCIATION_RAYS,),
        "**rays** green: matched, orange: new, red: rejected; **orange dots**: tentative",
    ),
    ((style.TRUTH_LANDMARKS,), "**black dots**: the true landmarks"),
    ((style.TRUTH_TRAJECTORY, style.TRUTH_ROBOT), "**grey line and dot**: the true path"),
    ((GPS_TRACK,), "**purple**: the GPS track"),
    (("world/divergence",), "**red marks**: where the checked filter diverged"),
    (
        ("world/divergence/expected",),
        "**grey, red outlines** (up close): the reference's and the checked filter's 3σ there",
    ),
)


# What hovering a mark of each kind names it, in the legend's words: the class of the
# entity (one class id, logged with its styling) in the annotation context of ``world``
KIND_NAMES: tuple[tuple[str, str], ...] = (
    (style.ROBOT, "the robot"),
    (style.HEADING, "the robot's heading"),
    (style.TRAJECTORY, "the estimated path"),
    (style.POSE_UPDATED, "the pose's 3σ after the update"),
    (style.POSE_PREDICTED, "the pose's 3σ after the predict"),
    (style.POSE_UPDATED_HISTORY, "the pose's 3σ after the update"),
    (style.POSE_PREDICTED_HISTORY, "the pose's 3σ after the predict"),
    (style.OBSERVATIONS, "a measurement"),
    (ASSOCIATION_RAYS, "an association ray (green: matched, orange: new, red: rejected)"),
    (ASSOCIATION_TENTATIVE, "a tentative landmark"),
    (style.TRUTH_ROBOT, "the true robot"),
    (style.TRUTH_TRAJECTORY, "the true path"),
    (GPS_TRACK, "the GPS track"),
)
# The kinds' class ids: the top of Rerun's u16 ids, which the landmarks' classes (class
# id = landmark id) leave free; a landmark whose id is up there is labelled on its own
KIND_CLASSES_RESERVED = 32
FIRST_KIND_CLASS = 65536 - KIND_CLASSES_RESERVED
KIND_CLASS: dict[str, int] = {path: FIRST_KIND_CLASS + k for k, (path, _) in enumerate(KIND_NAMES)}


def kind_classes(run: str = "") -> tuple[list[int], list[str]]:
    """The class ids of the kinds of marks and their names; with ``run`` (a filter's or a
    variant's name, several runs sharing a recording) the names say whose they are."""
    suffix = f" ({run})" if run else ""
    return list(KIND_CLASS.values()), [f"{name}{suffix}" for _, name in KIND_NAMES]


def legend_markdown(has: Collection[str]) -> str:
    """The legend of the marks in ``has`` (entity paths with data, without a prefix), one
    line of " · "-separated entries; empty when none is drawn."""
    shown = [text for paths, text in ENTRIES if any(path in has for path in paths)]
    return " · ".join(shown)


def markdown_document(text: str) -> rr.TextDocument:
    """A markdown text document (the legend, a study's summary)."""
    return rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN)
