"""Every relative link in README.md and docs/ leads somewhere: the file exists and, with a #anchor, one of its
headings has that anchor (GitHub's rule: lower case, letters, digits, spaces as hyphens, `-1`, `-2` for repeats).
Docs get split and moved (session logs to docs/history/); a dead link is what a reader meets first."""

import re
import unicodedata
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)|^\[[^\]]+\]:\s*(\S+)", re.MULTILINE)  # inline [text](target) and reference [name]: target


def anchors(md: Path) -> set[str]:
    out, seen, fenced = set(), {}, False
    for line in md.read_text().splitlines():
        fenced ^= line.startswith("```")
        heading = None if fenced else re.match(r"#{1,6}\s+(.*)", line)
        if heading:
            slug = "".join(c for c in heading[1].strip().lower() if unicodedata.category(c)[0] in "LN" or c in " -_").replace(" ", "-")
            n = seen[slug] = seen.get(slug, -1) + 1
            out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def dead_links(files: list[Path]) -> list[str]:
    dead = []
    for md in files:
        for target in (inline or reference for inline, reference in LINK.findall(md.read_text())):
            if re.match(r"[a-z]+:", target):  # https:, mailto:
                continue
            path, _, anchor = target.partition("#")
            linked = (md.parent / path) if path else md
            if not linked.exists() or (anchor and linked.suffix == ".md" and anchor not in anchors(linked)):
                dead.append(f"{md.name}: {target}")
    return dead


def test_relative_links_and_anchors_resolve():
    files = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    assert len(files) > 5
    assert dead_links(files) == []


def test_a_dead_link_or_anchor_is_found(tmp_path):
    (tmp_path / "b.md").write_text("# Results × 2 – now\n```\n# not a heading\n```\n## Results × 2 – now\n")
    (tmp_path / "a.md").write_text("[ok](b.md#results--2--now-1) [gone](c.md) [no](b.md#not-a-heading) [self](#top)\n# Top\n[r]: b.md#results\n")
    assert dead_links([tmp_path / "a.md"]) == ["a.md: c.md", "a.md: b.md#not-a-heading", "a.md: b.md#results"]
