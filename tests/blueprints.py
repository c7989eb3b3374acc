"""Read a recording's default layout back and match it against the entities with data.

A view shows an entity when the entity is of the view's kind (a scalar in a plot, a
text log in a log view, ...) and the view's contents query takes it; the views are those
reachable from the viewport's root container (a tab not open counts: one click shows it).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# The components that are data (not styling) and the view classes that draw them.
DATA_COMPONENTS: dict[str, frozenset[str]] = {
    "Scalars:scalars": frozenset({"TimeSeries"}),
    "Points2D:positions": frozenset({"2D"}),
    "LineStrips2D:strips": frozenset({"2D"}),
    "Arrows2D:vectors": frozenset({"2D"}),
    "Boxes2D:half_sizes": frozenset({"2D"}),
    "SegmentationImage:buffer": frozenset({"2D"}),
    "Image:buffer": frozenset({"2D"}),
    "TextDocument:text": frozenset({"TextDocument"}),
    "TextLog:text": frozenset({"TextLog"}),
}


@dataclass
class View:
    """One view of the layout: its class, name, origin, query and the entities it shows."""

    kind: str
    name: str
    origin: str
    query: list[str]
    shown: set[str] = field(default_factory=set)
    properties: dict[str, dict[str, Any]] = field(default_factory=dict)

    def takes(self, entity: str) -> bool:
        """Whether the contents query includes ``entity`` (the most specific rule wins)."""
        best: tuple[int, bool] | None = None
        for rule in self.query:
            for expression in rule.split("\n"):
                expression = expression.strip()
                if not expression:
                    continue
                include = not expression.startswith("-")
                expression = expression.lstrip("+- ").replace("$origin", self.origin)
                expression = "/" + expression.strip("/") if expression != "/" else "/"
                if expression.endswith("/**"):
                    base = expression[: -len("/**")] or "/"
                    hit = entity == base or entity.startswith(base.rstrip("/") + "/")
                    weight = 2 * len(base)
                else:
                    hit = entity == expression
                    weight = 2 * len(expression) + 1
                if hit and (best is None or weight >= best[0]):
                    best = (weight, include)
        return best is not None and best[1]


@dataclass
class Layout:
    """The views of a recording's blueprint and the entities with data, by kind."""

    views: list[View]
    data: dict[str, set[str]]  # entity path -> the view classes that can draw it
    time_panel: dict[str, Any]
    # the side panels' blueprint fields: "PanelBlueprint:state" 1 hidden, 2 collapsed,
    # 3 expanded, by panel ("blueprint_panel": the recordings and the views' tree)
    panels: dict[str, dict[str, Any]] = field(default_factory=dict)

    def unshown(self) -> list[str]:
        """The entities with data that no view shows."""
        return sorted(
            entity
            for entity, kinds in self.data.items()
            if not any(view.kind in kinds and view.takes(entity) for view in self.views)
        )

    def empty(self) -> list[str]:
        """The names of the views that show no entity with data."""
        return [
            view.name
            for view in self.views
            if not any(
                view.kind in kinds and view.takes(entity) for entity, kinds in self.data.items()
            )
        ]

    def view(self, name: str) -> View:
        (found,) = [view for view in self.views if view.name == name]
        return found

    def showing(self, entity: str) -> list[View]:
        """The views that show ``entity``."""
        kinds = self.data.get(entity, set())
        return [view for view in self.views if view.kind in kinds and view.takes(entity)]


def _rows(batch: Any) -> Iterator[dict[str, Any]]:
    table = {name: batch.column(name).to_pylist() for name in batch.schema.names}
    for values in zip(*table.values(), strict=True):
        yield dict(zip(table, values, strict=True))


def read_layout(path: Path) -> Layout:
    """The (last) blueprint of ``path`` and the entities with data of its recording."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    fields: dict[str, dict[str, Any]] = {}
    for chunk in reader.stream(store=reader.blueprints()[-1]):
        for row in _rows(chunk.to_record_batch()):
            for name, value in row.items():
                if ":" in name and value is not None:
                    fields.setdefault(chunk.entity_path, {})[name] = value
    root = bytes(fields["/viewport"]["ViewportBlueprint:root_container"][0])
    reachable: list[str] = []

    def walk(node: str) -> None:
        reachable.append(node)
        for child in fields.get(f"/{node}", {}).get("ContainerBlueprint:contents", []):
            walk(child)

    import uuid

    walk(f"container/{uuid.UUID(bytes=root)}")
    views = []
    for node in reachable:
        if not node.startswith("view/"):
            continue
        own = fields[f"/{node}"]
        origin = own["ViewBlueprint:space_origin"][0]
        views.append(
            View(
                kind=own["ViewBlueprint:class_identifier"][0],
                name=own.get("ViewBlueprint:display_name", [""])[0],
                origin="/" + origin.strip("/") if origin.strip("/") else "/",
                query=list(fields[f"/{node}/ViewContents"]["ViewContents:query"]),
                properties={
                    key.removeprefix(f"/{node}/"): value
                    for key, value in fields.items()
                    if key.startswith(f"/{node}/")
                },
            )
        )
    data: dict[str, set[str]] = {}
    for chunk in reader.stream():
        if chunk.entity_path.startswith("/__"):
            continue
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name in DATA_COMPONENTS and any(
                value for value in batch.column(name).to_pylist() if value
            ):
                data.setdefault(chunk.entity_path, set()).update(DATA_COMPONENTS[name])
    for view in views:
        view.shown = {e for e, kinds in data.items() if view.kind in kinds and view.takes(e)}
    panels = {name: fields.get(f"/{name}", {}) for name in ("blueprint_panel", "selection_panel")}
    return Layout(views, data, fields.get("/time_panel", {}), panels)
