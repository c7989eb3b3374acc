"""The layering of the package: layers import downwards only, without circles, and the
numpy-only layers never load rerun, typer or an optional backend."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

# The packages below the logging layer: numpy and the standard library only
NUMPY_ONLY = ("core", "models", "io", "sim", "filters", "sandbox", "association", "evaluation",
              "sources", "runner", "check", "calibrate", "studies")  # fmt: skip
PACKAGE = Path(__file__).parents[1] / "ekfviz"


def _modules(*packages: str) -> list[str]:
    """Every module of the given ekfviz packages, by dotted name."""
    names = []
    for package in packages:
        for path in sorted((PACKAGE / package).rglob("*.py")):
            parts = path.relative_to(PACKAGE).with_suffix("").parts
            names.append(".".join(("ekfviz", *parts)).removesuffix(".__init__"))
    return names


def test_the_numpy_only_packages_do_not_import_rerun_typer_gtsam_or_dask() -> None:
    # the GTSAM backend is the one module that imports its extra (when --filter asks for it)
    modules = [m for m in _modules(*NUMPY_ONLY) if m != "ekfviz.filters.gtsam"]
    assert "ekfviz.filters.ekf" in modules and len(modules) > 40
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "banned = {'rerun', 'typer', 'rich', 'gtsam', 'dask', 'distributed', 'pandas', 'rosbags',"
        " 'watchfiles'}\n"
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
        "        if name == 'ekfviz.filters._kernel':\n"
        "            raise ImportError('not built')\n"
        "if sys.argv[1] == 'without':\n"
        "    sys.meta_path.insert(0, NoKernel())\n"
        "from ekfviz.filters.ekf import HAVE_KERNEL, EkfSlam\n"
        "from ekfviz.runner.replay import replay\n"
        "from ekfviz.sim.scenarios import classic\n"
        "last = list(replay(classic().run(seed=2).events))[-1].last\n"
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
    """The ekfviz modules each module of ``package`` imports (TYPE_CHECKING ones too).

    ``from pkg import name`` imports the module ``pkg.name`` where there is one (a
    package's ``__init__`` importing its own modules imports them, not itself), else
    ``pkg``."""
    import ast

    raw: dict[str, list[tuple[str, str | None]]] = {}
    for path in package.rglob("*.py"):
        name = ".".join((root, *path.relative_to(package).with_suffix("").parts))
        name = name.removesuffix(".__init__")
        found: list[tuple[str, str | None]] = []
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.extend((node.module, alias.name) for alias in node.names)
            elif isinstance(node, ast.Import):
                found.extend((alias.name, None) for alias in node.names)
        raw[name] = found
    graph: dict[str, set[str]] = {}
    for name, found in raw.items():
        targets = set()
        for module, attribute in found:
            target = f"{module}.{attribute}" if f"{module}.{attribute}" in raw else module
            if target in raw:
                targets.add(target)
        graph[name] = targets
    return graph


# The layers, lowest first: a module imports only from its own layer or lower ones. The
# shared vocabulary (types, events and records, truth, statistics) is at the bottom; the
# command line at the top. Where a module sits is said by the longest prefix that names it.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("ekfviz.core", "ekfviz.signals", "ekfviz.startup"),
    ("ekfviz.models",),
    ("ekfviz.io",),
    ("ekfviz.sim",),
    ("ekfviz.filters", "ekfviz.sandbox"),
    ("ekfviz.association",),
    ("ekfviz.evaluation",),
    ("ekfviz.sources",),
    ("ekfviz.runner",),
    ("ekfviz.check", "ekfviz.calibrate"),
    ("ekfviz.studies",),
    ("ekfviz.viz", "ekfviz.readback"),
    ("ekfviz.app", "ekfviz.samples"),
    ("ekfviz.cli", "ekfviz.__main__"),
)


def _layer(module: str) -> int | None:
    """The index in :data:`LAYERS` of the longest prefix naming ``module``, if any."""
    best: tuple[int, int] | None = None
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and (
                best is None or len(prefix) > best[1]
            ):
                best = (index, len(prefix))
    return None if best is None else best[0]


def _upward(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a higher layer (or of one no layer names)."""
    found = []
    for name, targets in sorted(graph.items()):
        if name == "ekfviz":  # the package itself: its version only
            continue
        for target in sorted(targets - {"ekfviz"}):
            low, high = _layer(target), _layer(name)
            if low is None or high is None or low > high:
                found.append(f"{name} (layer {high}) imports {target} (layer {low})")
    return found


def _circles(graph: dict[str, set[str]]) -> list[str]:
    """Every module that imports itself through others, with the shortest such path."""
    found = []
    for start in sorted(graph):
        parent: dict[str, str] = {}
        queue = [start]
        while queue and start not in parent:
            module = queue.pop(0)
            for target in sorted(graph[module]):
                if target not in parent:
                    parent[target] = module
                    queue.append(target)
        if start in parent:  # walk back from start to start
            path, module = [start], parent[start]
            while module != start:
                path.append(module)
                module = parent[module]
            found.append(" -> ".join([start, *reversed(path)]))
    return found


def test_no_import_circles_anywhere_in_ekfviz() -> None:
    assert _circles(_imports(PACKAGE, "ekfviz")) == []


def test_every_module_imports_only_from_its_layer_or_lower_ones() -> None:
    graph = _imports(PACKAGE, "ekfviz")
    assert "ekfviz.filters.ekf" in graph and "ekfviz.cli.replay" in graph
    assert _upward(graph) == []


def test_the_layer_check_can_fail() -> None:
    graph = {"ekfviz.models.classic": {"ekfviz.filters.ekf"}, "ekfviz.filters.ekf": set(),
             "ekfviz.nowhere": set()}  # fmt: skip
    assert _upward(graph) == [
        "ekfviz.models.classic (layer 1) imports ekfviz.filters.ekf (layer 4)"
    ]
    assert _upward({"ekfviz.cli.x": {"ekfviz.nowhere"}, "ekfviz.nowhere": set()}) == [
        "ekfviz.cli.x (layer 13) imports ekfviz.nowhere (layer None)"
    ]


def test_the_circle_check_can_fail(tmp_path: Path) -> None:
    (tmp_path / "a.py").write_text("from pkg.b import x\n")
    (tmp_path / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                   "    from pkg.a import y\n")  # fmt: skip
    graph = _imports(tmp_path, "pkg")
    assert "pkg.b" in graph["pkg.a"] and "pkg.a" in graph["pkg.b"]
    assert len(_circles(graph)) == 2


def test_the_recorder_is_in_parts_of_at_most_400_lines() -> None:
    viz = Path(__file__).parents[1] / "ekfviz" / "viz"
    parts = [viz / "recorder.py", *sorted((viz / "layers").glob("*.py"))]
    assert len(parts) >= 10
    for path in parts:
        lines = len(path.read_text().splitlines())
        assert lines <= 400, f"{path.name}: {lines} lines"


# The command line parses, calls one use case and prints: of ekfviz it imports the use
# cases (ekfviz.app) and its own program, consoles and option groups, nothing else
CLI_OWN = frozenset((
    "ekfviz.cli", "ekfviz.cli.program", "ekfviz.cli.console", "ekfviz.cli.options",
    "ekfviz.cli.sources", "ekfviz.cli.study", "ekfviz.cli.help", "ekfviz.cli.checking",
))  # fmt: skip
CLI_LIBRARIES = frozenset(("typer", "rich", "click"))


def _cli_reach(package: Path, root: str) -> list[str]:
    """Every import of a command-line module beyond what the command line may import."""
    import ast

    found = []
    for path in sorted(package.rglob("*.py")):
        name = ".".join((root, *path.relative_to(package).with_suffix("").parts))
        name = name.removesuffix(".__init__")
        imported: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                imported |= {
                    f"{node.module}.{a.name}" if node.module == "ekfviz" else node.module
                    for a in node.names
                }
            elif isinstance(node, ast.Import):
                imported |= {alias.name for alias in node.names}
        for module in sorted(imported):
            top = module.split(".")[0]
            if top == "ekfviz":
                if module in CLI_OWN or module == "ekfviz.app" or module.startswith("ekfviz.app."):
                    continue
            elif top in CLI_LIBRARIES or top in sys.stdlib_module_names:
                continue
            found.append(f"{name} imports {module}")
    return found


def test_the_command_line_imports_the_use_cases_its_options_and_consoles_only() -> None:
    assert _cli_reach(PACKAGE / "cli", "ekfviz.cli") == []


def test_the_command_line_import_check_can_fail(tmp_path: Path) -> None:
    (tmp_path / "replay.py").write_text(
        "import numpy\nfrom ekfviz.app.replay import replay\nfrom ekfviz.viz import Sinks\n"
        "from ekfviz import signals\nfrom ekfviz.cli.console import out\nimport typer, shlex\n"
    )
    assert _cli_reach(tmp_path, "ekfviz.cli") == [
        "ekfviz.cli.replay imports ekfviz.signals",
        "ekfviz.cli.replay imports ekfviz.viz",
        "ekfviz.cli.replay imports numpy",
    ]
