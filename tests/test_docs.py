"""The documentation: the README's promises, the site's sources, and prose that speaks of
the software only (no word of how the project was worked on)."""

from __future__ import annotations

import importlib.util
import io
import json
import re
import tokenize
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"

# Words that speak of how the project is worked on, not of the software: numbered stops,
# issues and sessions, the people's roles, rounds of work, the checks the work was judged
# by. A reader of ekfviz's documentation or code has no use for any of them.
WORK_WORDS = re.compile(
    r"\bstops? \d"  # "stop 39", "stops 36 to 39"
    r"|\bissues? #?\d|\bissue:|\(#\d+\)"  # "issue 26", "Issue 26.3", "(issue: ...)", "(#23)"
    r"|\b(?:helper|lead|review|work|working|this|that|next|previous|last|earlier)"
    r" sessions?\b"
    r"|(?-i:\bH\d+\b)"  # "H12"
    r"|\blead\b(?! to\b)(?!s? (?:the|a|an) )"  # the lead, not "lead to"
    r"|\b(?:this|last|next|previous|that|each|every|a later) round\b|\bround \d"
    r"|\bworktree|\bhidden[- ]check|\bthe issue's|\bof the issue\b",
    re.IGNORECASE,
)

# Where the prose is: whole files, and the comments and strings of source files.
PROSE_FILES = ("README.md", "CHANGELOG.md", "benchmarks/RESULTS.md", "mkdocs.yml",
               "Makefile", "pyproject.toml", "setup.py", ".ci/run")  # fmt: skip
SOURCE_FOLDERS = ("ekfviz", "benchmarks", "examples", "docs", "tests")
# (this file's own examples of the words stay out)
SKIPPED_FILES = ("tests/test_docs.py",)


def _comments_and_strings(path: Path) -> Iterator[tuple[int, str]]:
    """The comments and string literals of a Python file, by line."""
    tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
    for token in tokens:
        if token.type in (tokenize.COMMENT, tokenize.STRING) or (
            token.type == getattr(tokenize, "FSTRING_MIDDLE", -1)
        ):
            yield token.start[0], token.string


def _c_comments(path: Path) -> Iterator[tuple[int, str]]:
    """The comments of a C file, by the line they start on."""
    text = path.read_text(encoding="utf-8")
    for match in re.finditer(r"/\*.*?\*/|//[^\n]*", text, re.DOTALL):
        yield text.count("\n", 0, match.start()) + 1, match.group()


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """A prose file's lines; a notebook's cells' lines."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".ipynb":
        text = "\n".join("".join(cell["source"]) for cell in json.loads(text)["cells"])
    yield from enumerate(text.splitlines(), start=1)


def _prose(path: Path) -> Iterator[tuple[int, str]]:
    if path.suffix in (".py", ".pyi"):
        return _comments_and_strings(path)
    if path.suffix in (".c", ".h"):
        return _c_comments(path)
    return _lines(path)


def work_words(paths: list[Path]) -> list[str]:
    """Every place in ``paths`` whose prose speaks of how the project was worked on."""
    found = []
    for path in paths:
        for line, text in _prose(path):
            for match in WORK_WORDS.finditer(text):
                where = line + text.count("\n", 0, match.start())
                found.append(f"{path.relative_to(ROOT)}:{where}: {match.group()!r}")
    return found


def _tree_prose() -> list[Path]:
    paths = [ROOT / name for name in PROSE_FILES if (ROOT / name).is_file()]
    suffixes = {".py", ".pyi", ".c", ".h", ".md", ".ipynb"}
    for folder in SOURCE_FOLDERS:
        paths += sorted(
            p for p in (ROOT / folder).rglob("*") if p.suffix in suffixes and p.is_file()
        )
    return sorted(
        {p for p in paths if "__pycache__" not in p.parts} - {ROOT / name for name in SKIPPED_FILES}
    )


def test_the_prose_speaks_of_the_software_only() -> None:
    paths = _tree_prose()
    assert len(paths) > 100 and README in paths and DOCS / "cli.md" in paths
    assert any(p.relative_to(ROOT).parts[0] == "tests" for p in paths)
    assert work_words(paths) == []


@pytest.mark.parametrize(
    "text",
    [
        "### Lead (stop 39): students' code",
        "measured three times at stop 39",
        "the targets of issue 26.3, point 3",
        "calibration that validates (#23)",
        "Three helper sessions tried the tool (H5)",
        "# the lead's merge of H12",
        "at the start of this round",
        "the hidden check's targets",
    ],
)
def test_the_prose_check_finds_the_words_of_the_work(text: str) -> None:
    assert WORK_WORDS.search(text), text


@pytest.mark.parametrize(
    "text",
    [
        "a process it starts in a session of its own",
        "a DISPLAY left from a session that ended",
        "the covariance is symmetric up to round-off",
        "H P H^T + R with H (2, 3+2N)",
        "a wrong sign may lead to a divergence",
        "the issue date of the licence",  # "issue" without a number
    ],
)
def test_the_prose_check_leaves_the_software_words(text: str) -> None:
    assert not WORK_WORDS.search(text), text


def test_the_prose_check_reads_comments_and_strings_not_code(tmp_path: Path) -> None:
    source = tmp_path / "x.py"
    source.write_text('H1 = 1  # fine\nstop_3 = 2\n"""since stop 39"""\n# issue 26\n')
    found = [entry.split(": ", 1)[1] for entry in work_words_in(source)]
    assert found == ["'stop 3'", "'issue 2'"]


def work_words_in(path: Path) -> list[str]:
    """:func:`work_words` of a file outside the tree (its path shown as given)."""
    return [
        f"{path}:{line}: {match.group()!r}"
        for line, text in _prose(path)
        for match in WORK_WORDS.finditer(text)
    ]


# -- the README -------------------------------------------------------------------------------


def test_the_readme_is_short_and_links_to_what_exists() -> None:
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [link for link in links if "://" not in link]
    assert "docs/getting-started.md" in local and "docs/screenshot.png" in local
    assert [link for link in local if not (ROOT / link).exists()] == []


def test_the_readme_sets_up_with_the_two_commands_the_makefile_has() -> None:
    text = README.read_text(encoding="utf-8")
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    for target in ("demo", "test"):
        assert re.search(rf"^make {target}\b", text, re.MULTILINE), target
        assert re.search(rf"^{target}:", makefile, re.MULTILINE), target


def test_every_section_the_readme_links_is_a_heading_of_its_page() -> None:
    from markdown.extensions.toc import slugify  # as the site names its headings

    text = README.read_text(encoding="utf-8")
    anchors = re.findall(r"\]\((docs/[\w-]+\.md)#([\w-]+)\)", text)
    assert len(anchors) >= 8
    missing = []
    for page, anchor in anchors:
        headings = re.findall(r"^#+ (.+)$", (ROOT / page).read_text(encoding="utf-8"), re.M)
        if anchor not in {slugify(heading, "-") for heading in headings}:
            missing.append(f"{page}#{anchor}")
    assert missing == []


def test_every_site_page_the_readme_links_is_in_the_site() -> None:
    text = README.read_text(encoding="utf-8")
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = set(re.findall(r"\(docs/([\w-]+\.md)", text))
    assert len(pages) >= 8
    assert [page for page in sorted(pages) if f": {page}" not in nav] == []


# -- the site ---------------------------------------------------------------------------------


def _hook(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, DOCS / "hooks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_command_line_reference_holds_every_command_and_option() -> None:
    import typer

    from ekfviz.cli import COMMANDS, load

    markdown = _hook("cli_reference").cli_markdown()
    group = typer.main.get_command(load())
    root = group.context_class(group, info_name="ekfviz")
    for name in COMMANDS:
        assert f"\n## ekfviz {name}\n" in markdown, name
        command = group.get_command(root, name)
        section = markdown.split(f"\n## ekfviz {name}\n", 1)[1].split("\n## ", 1)[0]
        for param in command.get_params(root):
            if param.param_type_name == "option" and not param.hidden:
                assert f"`{param.opts[0]}" in section, (name, param.opts[0])
    # help text is shown as written, never read as HTML or Markdown
    assert "filters/&lt;name&gt;/" in markdown and "<name>" not in markdown


def test_the_command_line_reference_replaces_its_marker_only() -> None:
    hook = _hook("cli_reference")
    assert hook.on_page_markdown("# A page\n") == "# A page\n"
    page = hook.on_page_markdown(f"# Command line\n\n{hook.MARKER}\n")
    assert hook.MARKER not in page and "## ekfviz replay" in page


def test_the_sites_pages_are_the_ones_the_nav_names() -> None:
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    named = set(re.findall(r": ([\w-]+\.md)$", nav, re.MULTILINE))
    written = {p.name for p in DOCS.glob("*.md")}
    assert named - written == {"results.md"}  # made from benchmarks/RESULTS.md
    assert written - named == set()
