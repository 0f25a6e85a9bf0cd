"""Docs that stay true: every package (a folder under splat_core/ or app/ with an __init__.py) is in
docs/design.md's layout and every folder the layout names there exists; every dated log in
docs/history/ and every page in docs/ is linked from docs/index.md, and every link there resolves."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def packages() -> set[str]:
    return {str(f.parent.relative_to(ROOT)) for top in ("splat_core", "app") for f in (ROOT / top).rglob("__init__.py")}


def layout_folders() -> set[str]:
    """The folders design.md's layout block names, as paths: a name ending in '/' in a line's name
    column (before the description), under the nearest less indented folder above it."""
    text = (DOCS / "design.md").read_text()
    block = text.split("## Layout", 1)[1].split("\n## ", 1)[0]
    found, parents = set(), []          # parents: (indent, path) of the enclosing folders
    for line in block.splitlines():
        if not line.startswith("    ") or not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        name_column = re.split(r"\s{2,}", line.strip(), maxsplit=1)[0]
        while parents and parents[-1][0] >= indent:
            parents.pop()
        base = parents[-1][1] + "/" if parents else ""
        folders = [n.strip() for n in name_column.split(",") if n.strip().endswith("/")]
        for n in folders:
            found.add(base + n.rstrip("/"))
        if len(folders) == 1 and name_column.endswith("/"):
            parents.append((indent, base + folders[0].rstrip("/")))
    return found


def test_the_layout_names_every_package_and_only_folders_that_exist():
    named = layout_folders()
    assert {"splat_core", "app", "splat_core/render", "app/viewer"} <= named     # the parser reads the block
    missing = sorted(packages() - named)
    assert not missing, f"packages missing from docs/design.md's layout: {missing}"
    ours = {n for n in named if n.split("/")[0] in ("splat_core", "app")}
    gone = sorted(n for n in ours if not (ROOT / n).is_dir())
    assert not gone, f"docs/design.md's layout names folders that do not exist: {gone}"


def test_the_index_links_every_log_and_page_and_its_links_resolve():
    index = (DOCS / "index.md").read_text()
    links = set(re.findall(r"\]\(([^)#\s]+)", index))
    logs = {f"history/{f.name}" for f in (DOCS / "history").glob("*.md")}
    assert not sorted(logs - links), f"docs/history logs missing from docs/index.md: {sorted(logs - links)}"
    pages = {f.name for f in DOCS.glob("*.md")} - {"index.md"}
    assert not sorted(pages - links), f"docs pages missing from docs/index.md: {sorted(pages - links)}"
    broken = sorted(link for link in links if "://" not in link and not (DOCS / link).exists())
    assert not broken, f"docs/index.md links to missing files: {broken}"
