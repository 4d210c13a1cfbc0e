"""The README stays short, its first block stays the two commands, and no doc links to a missing file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted([README, *(ROOT / "docs").glob("*.md")])

FENCE = re.compile(r"^```[a-z]*\n(.*?)^```", re.M | re.S)  # as bench/newcomer.py reads it
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)\)")


def commands(block: str) -> list[str]:
    """The command lines of a fenced block: not blank, not a comment."""
    return [line.strip() for line in block.splitlines() if line.strip() and not line.strip().startswith("#")]


def relative_links(markdown: str) -> list[str]:
    """Link and image targets outside code, without their #anchor; web and mail links left out."""
    prose = INLINE_CODE.sub("", FENCE.sub("", markdown))
    targets = [target.split("#", 1)[0] for target in LINK.findall(prose)]
    return [t for t in targets if t and not re.match(r"[a-z][a-z0-9+.-]*:", t)]


def test_readme_is_at_most_250_lines() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; move details into docs/"


def test_the_first_block_is_the_demo_then_the_tests() -> None:
    first = FENCE.search(README.read_text(encoding="utf-8"))
    assert first is not None, "README.md has no fenced block"
    lines = commands(first.group(1))
    assert len(lines) == 2, lines
    assert "a3d-run samples/" in lines[0] and lines[1] == "./scripts/test"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_at_files(doc: Path) -> None:
    links = relative_links(doc.read_text(encoding="utf-8"))
    missing = [t for t in links if not (doc.parent / t).exists()]
    assert not missing, f"{doc.relative_to(ROOT)} links to missing files: {missing}"


def test_the_link_reader_finds_links_and_skips_code() -> None:
    text = "See [a](docs/a.md#x), ![b](img.png) and [web](https://x.org).\n`[c](c.md)`\n```\n[d](d.md)\n```\n"
    assert relative_links(text) == ["docs/a.md", "img.png"]


MEASURED = re.compile(r"(?<![\w.])\d+\.\d+(?!\w|\.\d)")  # decimals (a sentence's full stop may follow)


def test_the_model_card_quotes_numbers_from_their_home_pages() -> None:
    """Each number the README's model card quotes stands in a docs page it links (its one home), so a
    number re-measured there and left stale here fails (the samples' mAP is also re-measured by
    tests/test_samples.py)."""
    text = README.read_text(encoding="utf-8")
    card = text[text.index("## Models") : text.index("\n## ", text.index("## Models") + 1)]
    homes = sorted({ROOT / t for t in relative_links(card) if t.startswith("docs/") and t.endswith(".md")})
    assert homes, "the model card links no docs page"
    pages = "\n".join(page.read_text(encoding="utf-8") for page in homes)
    quoted = set(MEASURED.findall(INLINE_CODE.sub("", FENCE.sub("", card))))
    assert {"50.9", "57.3", "74.4"} <= quoted, quoted
    missing = sorted(n for n in quoted if n not in pages)
    assert not missing, f"numbers in the README's model card that no linked page holds: {missing}"
