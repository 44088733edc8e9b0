"""The examples of docs/api.md run, in order, in one namespace, from the repository root."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "api.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_doc_has_examples_for_every_call():
    code = "\n".join(python_blocks(DOC.read_text()))
    for call in ("refine.refine_path(", "refine.load_problem(", "refine.solve(", ".write(", "previous="):
        assert call in code


@pytest.mark.slow
def test_every_example_of_the_api_doc_runs(monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    namespace: dict = {"__name__": "api_doc"}
    blocks = python_blocks(DOC.read_text())
    assert len(blocks) >= 6
    for k, block in enumerate(blocks):
        try:
            exec(compile(block, f"{DOC.name} block {k + 1}", "exec"), namespace)
        except Exception as e:  # name the block that failed
            raise AssertionError(f"docs/api.md python block {k + 1} failed: {e!r}\n{block}") from e
    out = capsys.readouterr().out
    assert "positions: expected shape (N, 3) [m]" in out
