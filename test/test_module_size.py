"""No module of the project over 800 lines (issue 24: split along concepts before a file grows past what a
reader holds in mind). Fails naming every module over the limit and its length."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 800


def test_no_module_over_the_limit() -> None:
    files = sorted((ROOT / "src").rglob("*.py"))
    assert len(files) > 100  # the tree is there
    long = {
        str(f.relative_to(ROOT)): n for f in files if (n := len(f.read_text(encoding="utf-8").splitlines())) > LIMIT
    }
    assert not long, f"modules over {LIMIT} lines (split along a concept): {long}"
