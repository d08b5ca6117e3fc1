"""The path a reader takes: a notebook opened on a fresh clone with ``TRAIN = False`` in ``quick``,
reading only what the repository ships. Every notebook runs in full, the quick ones here and the
ones that play shipped agents for minutes in ``test_reader_path_slow.py`` (another file, so that
the two test workers share them); each must run without an error, print no placeholder, print a
headline line for every headline it declares, and print the summary's numbers there (mean,
interval and seeds)."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from wmthesis.summary import HEADLINE_LINE, variant_label

ROOT = Path(__file__).resolve().parents[1]
FAST = ("00_environments", "01_sokoban_world_models", "02_boxing_world_models", "03_boxing_world_models_alphazero",
        "04_planet_sokoban", "06_kl_scale_free_nats_search", "07_sokoban_search", "09_planet_boxing_value",
        "11_planning_budget")


@pytest.fixture(scope="module")
def shipped(tmp_path_factory) -> Path:
    """A fresh clone's data folder: what git tracks, nothing a run left behind."""
    tracked = os.popen(f"git -C {ROOT} ls-files data").read().split()
    if not tracked:
        pytest.skip("not a git checkout")
    data = tmp_path_factory.mktemp("clone") / "data"
    for file in tracked:
        target = data / Path(file).relative_to("data")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / file, target)
    return data


@pytest.mark.parametrize("name", FAST)
def test_a_notebook_opens_from_what_ships_as_a_reader_opens_it(name, shipped, monkeypatch):
    opens_as_a_reader_opens_it(name, shipped, monkeypatch)


def opens_as_a_reader_opens_it(name: str, shipped: Path, monkeypatch) -> None:
    """Run notebook ``name`` from ``shipped`` in quick and check what it printed (module docstring)."""
    from test_notebooks import missing_headlines, output_text

    monkeypatch.setenv("WMTHESIS_DATA", str(shipped))
    monkeypatch.setenv("WMTHESIS_PROFILE", "quick")
    notebook = nbformat.read(ROOT / "notebooks" / f"{name}.ipynb", as_version=4)
    NotebookClient(notebook, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(ROOT / "notebooks")}}).execute()
    outputs = "\n".join(output_text(cell) for cell in notebook.cells if cell.cell_type == "code")
    assert "TRAIN = True" not in outputs
    path = ROOT / "notebooks" / f"{name}.ipynb"
    assert not missing_headlines(path, outputs), f"{name}: prints no headline line for {missing_headlines(path, outputs)}"
    summary = {(r["experiment"], variant_label(r["experiment"], r["variant"]), r["profile"]): r
               for r in json.loads((ROOT / "data" / "results" / "summary.json").read_text())["rows"]}
    for line in HEADLINE_LINE.finditer(outputs):
        row = summary[line["experiment"], line["variant"], line["profile"]]
        assert (float(line["mean"]), int(line["n"]), list(map(int, line["seeds"].split()))) == \
            (round(row["mean"], 1), row["n"], row["seeds"]), line[0]
        if row["ci_low"] is not None:  # and its interval, to the digit
            assert f"[{row['ci_low']:.1f}, {row['ci_high']:.1f}]" in line[0], line[0]
