"""The layering of the package: the numpy-only core never loads rerun or typer."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_core_io_and_sim_do_not_import_rerun_typer_gtsam_or_dask() -> None:
    code = (
        "import sys\n"
        "import ekfviz.core.filter, ekfviz.core.replay, ekfviz.core.evaluation\n"
        "import ekfviz.core.health\n"
        "import ekfviz.core.consistency, ekfviz.sim.montecarlo, ekfviz.studies.sweep\n"
        "import ekfviz.studies.runs, ekfviz.filters, ekfviz.core.check, ekfviz.models.classic\n"
        "import ekfviz.io.classic, ekfviz.io.extended, ekfviz.io.truth, ekfviz.sim.scenarios\n"
        "import ekfviz.io.mrclam, ekfviz.io.detect, ekfviz.sim.mrclam\n"
        "import ekfviz.core.calibrate, ekfviz.core.gating\n"
        "import ekfviz.models.classic, ekfviz.core.correlation, ekfviz.filters\n"
        "import ekfviz.studies.executors, ekfviz.io.trajectory\n"
        "banned = {'rerun', 'typer', 'rich', 'gtsam', 'dask', 'distributed'}\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in banned)\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == ""


def test_the_logging_layer_does_load_rerun() -> None:
    """The check above can fail: importing the logging layer does bring rerun in."""
    code = "import sys, ekfviz.viz; print('rerun' in sys.modules)"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "True"


def test_bundled_samples_are_what_ekfviz_simulate_writes(tmp_path: Path) -> None:
    from ekfviz.cli import app
    from ekfviz.samples import SAMPLES, simulate_arguments

    data = Path(__file__).parents[1] / "data"
    for stem in SAMPLES:
        app(simulate_arguments(tmp_path, stem), standalone_mode=False)
        for name in (f"{stem}.txt", f"{stem}_truth.json"):
            made, bundled = (tmp_path / name).read_bytes(), (data / name).read_bytes()
            assert made == bundled, f"data/{name} differs: regenerate it with make sample"
    assert sum(f.stat().st_size for f in data.iterdir()) < 2_000_000


def test_without_the_compiled_kernel_the_numpy_code_stands_in() -> None:
    """As on a machine that had no C compiler at install: the import of the kernel
    fails, and a replay still runs, with the same result as the one with the kernel."""
    code = (
        "import sys\n"
        "class NoKernel:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'ekfviz.core._kernel':\n"
        "            raise ImportError('not built')\n"
        "if sys.argv[1] == 'without':\n"
        "    sys.meta_path.insert(0, NoKernel())\n"
        "from ekfviz.core.filter import HAVE_KERNEL, EkfSlam\n"
        "from ekfviz.core.replay import replay\n"
        "from ekfviz.sim.scenarios import classic\n"
        "last = list(replay(classic().run(seed=2).events))[-1]\n"
        "print(HAVE_KERNEL, EkfSlam()._compiled, repr(last.pose.tolist()))\n"
    )

    def run(which: str) -> list[str]:
        result = subprocess.run(
            [sys.executable, "-c", code, which], capture_output=True, text=True, check=True
        )
        return result.stdout.split(maxsplit=2)

    without = run("without")
    assert without[:2] == ["False", "False"]
    with_kernel = run("with")
    if with_kernel[0] == "True":  # built here: both give the same pose, to round-off
        first = [float(v) for v in without[2].strip("[]\n").split(",")]
        second = [float(v) for v in with_kernel[2].strip("[]\n").split(",")]
        assert max(abs(a - b) for a, b in zip(first, second, strict=True)) < 1e-12


def _imports(package: Path, root: str) -> dict[str, set[str]]:
    """The ekfviz modules each module of ``package`` imports (TYPE_CHECKING ones too)."""
    import ast

    graph: dict[str, set[str]] = {}
    for path in package.rglob("*.py"):
        name = ".".join((root, *path.relative_to(package).with_suffix("").parts))
        name = name.removesuffix(".__init__")
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module)
                found.update(f"{node.module}.{alias.name}" for alias in node.names)
            elif isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
        graph[name] = found
    return {name: {m for m in found if m in graph} for name, found in graph.items()}


def test_no_import_circles_in_the_numpy_only_packages() -> None:
    package = Path(__file__).parents[1] / "ekfviz"
    graph = _imports(package, "ekfviz")
    numpy_only = ("ekfviz.core", "ekfviz.models", "ekfviz.io", "ekfviz.sim", "ekfviz.studies",
                  "ekfviz.filters")  # fmt: skip
    for start in (name for name in graph if name.startswith(numpy_only)):
        stack, seen = [start], set[str]()
        while stack:
            for target in graph[stack.pop()]:
                assert target != start, f"{start} imports itself through {sorted(seen)}"
                if target not in seen:
                    seen.add(target)
                    stack.append(target)


def test_the_circle_check_can_fail(tmp_path: Path) -> None:
    (tmp_path / "a.py").write_text("from pkg.b import x\n")
    (tmp_path / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                   "    from pkg.a import y\n")  # fmt: skip
    graph = _imports(tmp_path, "pkg")
    assert "pkg.b" in graph["pkg.a"] and "pkg.a" in graph["pkg.b"]


def test_no_import_circles_in_the_viz_package() -> None:
    """The recorder's parts, the association view and the rest of ``ekfviz.viz`` import
    one another one way only (``from ekfviz.viz import style`` imports ``style``, not the
    package's ``__init__``, which gathers the API)."""
    package = Path(__file__).parents[1] / "ekfviz"
    graph = _imports(package, "ekfviz")
    viz = {
        name: {m for m in found if m.startswith("ekfviz.viz.")}
        for name, found in graph.items()
        if name.startswith("ekfviz.viz.")
    }
    assert "ekfviz.viz.layers.landmarks" in viz["ekfviz.viz.recorder"]
    for start in viz:
        stack, seen = [start], set[str]()
        while stack:
            for target in viz.get(stack.pop(), set()):
                assert target != start, f"{start} imports itself through {sorted(seen)}"
                if target not in seen:
                    seen.add(target)
                    stack.append(target)


def test_the_recorder_is_in_parts_of_at_most_400_lines() -> None:
    viz = Path(__file__).parents[1] / "ekfviz" / "viz"
    parts = [viz / "recorder.py", *sorted((viz / "layers").glob("*.py"))]
    assert len(parts) >= 10
    for path in parts:
        lines = len(path.read_text().splitlines())
        assert lines <= 400, f"{path.name}: {lines} lines"
