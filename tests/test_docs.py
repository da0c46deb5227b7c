"""The README stays a ten-minute read and the docs hold together: README.md at most 250 lines, every
relative link in README.md and docs/*.md pointing to a file that exists (and, with an anchor, to a heading
of that file), docs/figures.md's generated blocks matching tools/docs_figures.py, and no machine path in
the docs. Reads files only."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]
MAX_README_LINES = 250

LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")


def _figures_tool():
    spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "tools" / "docs_figures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but hyphens and underscores dropped, spaces
    to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.+)$", text, re.M)}


def links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return [a or b for a, b in LINK.findall(text)]


def test_readme_is_short():
    n = len(README.read_text().splitlines())
    assert n <= MAX_README_LINES, f"README.md has {n} lines (at most {MAX_README_LINES}): move detail to docs/"


def test_readme_keeps_the_two_commands():
    text = README.read_text()
    assert "./tools/run" in text and "./tools/test" in text
    assert "exec ./tools/test" in (ROOT / ".ci" / "run").read_text()


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page):
    bad = []
    for target in links(page):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):          # http:, https:, mailto:, ws:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading '#{anchor}' in {dest.name}")
    assert not bad, f"{page.name}: " + "; ".join(bad)


def test_every_docs_page_is_reachable_from_the_readme():
    linked = set()
    for page in PAGES:
        for target in links(page):
            path = target.partition("#")[0]
            if path and not re.match(r"^[a-z][a-z0-9+.-]*:", path):
                linked.add((page.parent / path).resolve())
    missing = [p.name for p in DOCS if p.resolve() not in linked]
    assert not missing, f"docs pages no page links to: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_machine_paths(page):
    text = page.read_text()
    assert not re.search(r"/work/|/home/\w|/root/", text), page.name


def test_figures_blocks_match_their_commands():
    tool = _figures_tool()
    problems = tool.check((ROOT / "docs" / "figures.md").read_text())
    assert not problems, problems


def test_figures_check_catches_a_hand_edited_block():
    tool = _figures_tool()
    text = (ROOT / "docs" / "figures.md").read_text()
    name = next(iter(tool.BLOCKS))
    edited = tool.replace_block(text, name, f"<!-- BEGIN {name} -->\n| typed | 1.0 |\n<!-- END {name} -->")
    assert any(name in p for p in tool.check(edited))
    assert tool.check(edited.replace(f"<!-- BEGIN {name} -->", "", 1))      # a missing block too


def test_replace_block_leaves_the_rest_alone():
    tool = _figures_tool()
    text = "intro\n<!-- BEGIN a -->\nold\n<!-- END a -->\nmiddle\n<!-- BEGIN b -->\nkeep\n<!-- END b -->\n"
    out = tool.replace_block(text, "a", "<!-- BEGIN a -->\nnew\n<!-- END a -->")
    assert out == text.replace("old", "new")
    with pytest.raises(SystemExit):
        tool.replace_block(text, "c", "x")


def test_the_link_check_catches_broken_links(tmp_path):
    (tmp_path / "a.md").write_text("# Title\n\n## The loop's budget: `rtsim bench`\n\ntext\n")
    page = tmp_path / "b.md"
    page.write_text("[ok](a.md#the-loops-budget-rtsim-bench) [gone](c.md) [no anchor](a.md#nowhere)\n"
                    "```\n[in code](ignored.md)\n```\n")
    assert links(page) == ["a.md#the-loops-budget-rtsim-bench", "c.md", "a.md#nowhere"]
    assert "the-loops-budget-rtsim-bench" in anchors(tmp_path / "a.md")
    assert "nowhere" not in anchors(tmp_path / "a.md")
