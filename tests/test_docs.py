"""Code on the documentation pages and in the README runs: every ```python block, in a fresh namespace in a temporary
folder. (The site itself is built by `make docs`, warnings as errors, in .ci/run.)"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
BLOCKS = [(page, index, code) for page in PAGES
          for index, code in enumerate(re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.DOTALL))]


@pytest.mark.parametrize(("page", "index", "code"), BLOCKS, ids=[f"{p.relative_to(ROOT)}#{i}" for p, i, _ in BLOCKS])
def test_the_python_on_the_pages_runs(page: Path, index: int, code: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"{page.name} block {index}", "exec"), {"__name__": "__docs__"})  # noqa: S102 - the page's own code


def test_every_page_has_code_that_runs_and_every_system_has_a_page() -> None:
    assert len(BLOCKS) >= 4
    systems = {p.stem for p in (ROOT / "docs" / "systems").glob("*.md")}
    assert systems == {"head", "attitude9", "gaze", "bicycle", "walking", "ultrasonic"}
