"""docs/api.md as a new user meets it: every python block runs, one after another in one namespace,
on the agents the repository ships; each prints what the text block after it shows (``...``
stands for anything), and no block is longer than 15 lines.

    python tests/test_api_docs.py      # runs the blocks in docs/api/, refreshing its pictures
"""
from __future__ import annotations

import contextlib
import doctest
import io
import os
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "api.md"
BLOCK = re.compile(r"```python\n(.*?)```(?:\s*```text\n(.*?)```)?", re.S)


def blocks() -> list[tuple[str, str | None]]:
    """Each python block of docs/api.md with the output the text block after it shows (or None)."""
    return [(code, output) for code, output in BLOCK.findall(DOC.read_text())]


def run_blocks(folder: Path) -> list[tuple[str, str | None, str]]:
    """Run every block in ``folder`` (the current directory while they run): (code, expected, printed)."""
    import matplotlib

    matplotlib.use("Agg")
    namespace, ran, here = {}, [], Path.cwd()
    os.chdir(folder)
    try:
        for code, expected in blocks():
            printed = io.StringIO()
            with contextlib.redirect_stdout(printed):
                exec(compile(code, str(DOC), "exec"), namespace)
            ran.append((code, expected, printed.getvalue()))
    finally:
        os.chdir(here)
    return ran


def test_every_block_of_the_api_page_runs_and_prints_what_the_page_shows(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(REPO / "data"))  # the agents the repository ships
    checker = doctest.OutputChecker()
    ran = run_blocks(tmp_path)
    assert len(ran) == 8
    for code, expected, printed in ran:
        assert len(code.strip().splitlines()) <= 15, code
        if expected:
            assert checker.check_output(expected, printed, doctest.ELLIPSIS), f"{code}\nprinted:\n{printed}"
    assert {p.name for p in tmp_path.glob("*.png")} == {"vision.png", "dream.png", "open_loop.png", "sokoban.png", "still.png"}


def test_the_page_names_only_what_the_package_has():
    import wmthesis

    for name in re.findall(r"wmthesis\.(\w+)\(", DOC.read_text()):
        assert hasattr(wmthesis, name), name


if __name__ == "__main__":
    os.environ.setdefault("WMTHESIS_DATA", str(REPO / "data"))
    (REPO / "docs" / "api").mkdir(exist_ok=True)
    for code, expected, printed in run_blocks(REPO / "docs" / "api"):
        sys.stdout.write(printed)
