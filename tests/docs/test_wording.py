"""The README and the docs say what is true today, with the command behind each figure, never
the story of how it was found: no phrase of a work diary ("this code (", "the code before",
"for the lead", "as before", a "code: <hash>" stamp...) and none of the claims once found wrong
(the schema version 1, a token variable the daemon does not document, a constant "held at the
paper's value" where the description's is held).  History belongs in CHANGELOG.md."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Phrases of a diary: the work's story, not the program's state.
DIARY = [
    r"\bstop \d+\b", r"\bissue \d+\b", r"\bscratch\b", r"\bthis code \(", r"\bthe code before\b",
    r"\bfor the lead\b", r"\bas before\b", r"\bwhere it never did\b", r"\bthis round\b",
    r"\btoday's code\b", r"\bcode: [0-9a-f]{7,40}\b",
]
#: Claims once made and found wrong against the code.
WRONG = [
    r"schema version, 1\)", r"TACTILED_SERVER_TOKEN", r"held at the paper's value",
    r"cylindrical fingertip array",
]


def pages() -> list[Path]:
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def hits(patterns: list[str], text: str) -> list[str]:
    return [m.group(0) for p in patterns for m in re.finditer(p, text, re.IGNORECASE)]


def test_no_page_reads_as_a_diary() -> None:
    found = {str(p.relative_to(ROOT)): hits(DIARY, p.read_text()) for p in pages()}
    found = {k: v for k, v in found.items() if v}
    print("FIGURES docs_wording:", {"pages": len(pages())})
    assert len(pages()) >= 35
    assert found == {}


def test_no_page_repeats_a_claim_found_wrong() -> None:
    found = {str(p.relative_to(ROOT)): hits(WRONG, p.read_text()) for p in pages()}
    assert {k: v for k, v in found.items() if v} == {}


def test_the_check_sees_each_phrase() -> None:
    text = ("measured with this code (2d03a55) against the code before; code: 2193a5b; for the "
            "lead to confirm; exactly as before; stop 3 of issue 12; where it never did")
    assert len(hits(DIARY, text)) == 8
    assert hits(DIARY, "the code before's") == ["the code before"]
    assert hits(DIARY, "a stop at 1 N, as the code says; the issue's bars") == []
