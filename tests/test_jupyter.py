"""A chapter run through Jupyter's own command line, as the README tells a reader to: after
``pip install -r requirements.txt`` on a fresh clone, ``jupyter nbconvert --to notebook --execute``
runs notebook 04 with ``TRAIN = False`` in ``quick`` (its parameters cell: ``TRAIN`` is true only
in ``smoke``) from what the repository ships, in at most 5 minutes, without an error, printing its
chapter box and its stamp. (``test_reader_path.py`` runs every notebook through nbclient in this
process; this is the installed ``jupyter`` and the kernel it starts.)"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import nbformat
import pytest

from test_notebooks import output_text
from test_reader_path import ROOT, shipped  # noqa: F401 (the fixture: a fresh clone's data folder)
from wmthesis.chapters import chapter_box
from wmthesis.stamp import read_stamp

NOTEBOOK = ROOT / "notebooks" / "04_planet_sokoban.ipynb"
LIMIT_S = 300  # the target: notebook 04 from a fresh clone in at most 5 minutes


def test_jupyter_runs_notebook_04_from_what_ships_within_five_minutes(shipped, tmp_path):  # noqa: F811
    jupyter = Path(sys.executable).with_name("jupyter")  # the environment's own, as `. .venv/bin/activate` finds it
    assert jupyter.is_file(), f"no {jupyter}: requirements.txt installs jupyterlab (and with it nbconvert)"
    out = tmp_path / "04.ipynb"
    env = {**{k: v for k, v in os.environ.items() if k != "MPLBACKEND"},  # the kernel's own (inline), as a reader's
           "WMTHESIS_PROFILE": "quick", "WMTHESIS_DATA": str(shipped)}
    started = time.monotonic()
    try:
        ran = subprocess.run([str(jupyter), "nbconvert", "--to", "notebook", "--execute",
                              str(NOTEBOOK.relative_to(ROOT)), "--output", str(out)],
                             cwd=ROOT, env=env, capture_output=True, text=True, timeout=LIMIT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"jupyter nbconvert --execute {NOTEBOOK.name} ran past {LIMIT_S} s")
    took = time.monotonic() - started
    assert ran.returncode == 0, f"jupyter nbconvert exited {ran.returncode}:\n{ran.stderr[-3000:]}"
    assert took <= LIMIT_S, f"{NOTEBOOK.name} took {took:.0f} s through Jupyter (target {LIMIT_S} s)"

    notebook = nbformat.read(out, as_version=4)
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    errors = [o.get("ename") for cell in code for o in cell.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors, f"{NOTEBOOK.name}: error outputs {errors}"
    assert [cell.get("execution_count") for cell in code] == list(range(1, len(code) + 1)), \
        f"{NOTEBOOK.name}: its code cells did not run once each, top to bottom"
    outputs = "\n".join(output_text(cell) for cell in code)
    assert re.search(r"\*\*Verdict\**:", outputs), f"{NOTEBOOK.name}: printed no chapter box (its verdict line)"
    assert chapter_box("04", "quick", shipped / "results") in outputs, \
        f"{NOTEBOOK.name}: its chapter box is not the one the shipped runs give"
    found = read_stamp(output_text(code[-1]))
    assert found is not None, f"{NOTEBOOK.name}: its last cell printed no run stamp"
    assert (found["profile"], found["how"]) == ("quick", "from shipped runs"), \
        f"{NOTEBOOK.name}: not the reader's path (TRAIN = False in quick): {found}"
