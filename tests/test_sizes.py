"""Units a reader can hold (``tools/sizes.py``): no function over 100 lines and no module
over 800 anywhere in ekfviz."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).parents[1]


def _sizes() -> ModuleType:
    spec = importlib.util.spec_from_file_location("sizes", ROOT / "tools" / "sizes.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["sizes"] = module  # (its dataclasses look their module up)
    spec.loader.exec_module(module)
    return module


def test_ekfviz_has_no_function_over_100_lines_nor_module_over_800() -> None:
    sizes = _sizes()
    modules = sizes.modules()
    names = {str(path.relative_to(ROOT)) for path in modules}
    assert len(modules) > 180 and "ekfviz/sandbox/child.py" in names
    assert "ekfviz/viz/association.py" in names and "ekfviz/association/jcbb.py" in names
    assert [str(unit) for unit in sizes.oversized(modules)] == []


def test_the_size_check_can_fail(tmp_path: Path) -> None:
    sizes = _sizes()
    long = tmp_path / "long.py"
    body = "\n".join(f"    x{k} = {k}" for k in range(120))
    long.write_text(f"@decorated\ndef long() -> None:\n{body}\n" + "# -\n" * 700)
    found = [(unit.where, unit.lines) for unit in sizes.oversized([long], tmp_path)]
    assert found == [("long.py", 822), ("long.py:2 long", 122)]
