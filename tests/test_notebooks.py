"""The committed notebooks as a reader meets them: run top to bottom, on code that is in the
history, stamped, each headline number the summary's. (Every notebook also runs in ``smoke`` in the
suite, through nbval: ``testpaths`` in pyproject.toml.)"""
import ast
import json
import re
import subprocess
import time
from pathlib import Path

import pytest

from wmthesis.stamp import git_commit, read_stamp, stamp
from wmthesis.summary import HEADLINE_LINE, variant_label

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
# Committed outputs from before the stamp (issue 56): each leaves this set when it is re-run.
AWAITING_RERUN: set[str] = set()


def code_cells(path: Path) -> list[dict]:
    return [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]


def output_text(cell: dict) -> str:
    parts = []
    for output in cell.get("outputs", []):
        parts.append("".join(output.get("text", "")))
        data = output.get("data", {})
        parts += ["".join(data.get(kind, "")) for kind in ("text/plain", "text/markdown")]
    return "\n".join(parts)


def is_ancestor(older: str, newer: str) -> bool:
    """Whether commit ``older`` is ``newer`` or one of its ancestors in this checkout."""
    return subprocess.run(["git", "-C", str(ROOT), "merge-base", "--is-ancestor", older, newer],
                          capture_output=True).returncode == 0


def in_history(commit: str) -> bool:
    """Whether ``commit`` is HEAD or one of its ancestors in this checkout."""
    return is_ancestor(commit, "HEAD")


def imported_files(path: Path) -> list[str]:
    """The package's files that ``path``'s code cells import directly (a ``from wmthesis.x import
    y`` names module ``wmthesis.x.y`` where one exists, else ``wmthesis.x``), relative to the root."""
    names = set()
    for cell in code_cells(path):
        source = "\n".join(line for line in "".join(cell["source"]).splitlines() if not line.lstrip().startswith(("%", "!")))
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.Import):
                names |= {a.name for a in node.names if a.name.split(".")[0] == "wmthesis"}
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "wmthesis":
                names |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    files = []
    for name in names:
        base = ROOT / Path(*name.split("."))
        files += [str(f.relative_to(ROOT)) for f in (base.with_suffix(".py"), base / "__init__.py") if f.is_file()]
    return sorted(files)


def last_change(files: list[str]) -> str | None:
    """The last commit that changed any of ``files`` (None outside a git checkout)."""
    found = subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%H", "--", *files], capture_output=True,
                           text=True)
    return found.stdout.strip() or None


def check_notebook(path: Path) -> None:
    """Raise AssertionError unless ``path``'s code cells ran in order, without an error, and the
    last one carries a stamp of a committed, unchanged checkout in ``quick``."""
    cells = code_cells(path)
    assert [c.get("execution_count") for c in cells] == list(range(1, len(cells) + 1)), \
        f"{path.name}: its code cells did not run once each, top to bottom"
    errors = [o.get("ename") for c in cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors, f"{path.name}: error outputs {errors}"
    found = read_stamp(output_text(cells[-1]))
    assert found is not None, f"{path.name}: its last cell prints no run stamp (wmthesis.stamp.stamp)"
    assert not found["changes"], f"{path.name}: run on code that differed from commit {found['commit']}"
    assert in_history(found["commit"]), f"{path.name}: its stamp's commit {found['commit']} is not in the history"
    assert found["profile"] == "quick", f"{path.name}: committed outputs are quick's, not {found['profile']}'s"
    changed = last_change(imported_files(path))
    assert changed is None or is_ancestor(changed, found["commit"]), \
        f"{path.name}: run at {found['commit']}, before {changed[:7]} changed the modules it imports: re-run it"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_a_committed_notebook_ran_top_to_bottom_on_committed_code(path):
    if git_commit() is None:
        pytest.skip("not a git checkout: the stamps' commits cannot be looked up")
    if path.stem in AWAITING_RERUN:
        pytest.skip(f"{path.name}: committed outputs from before the run stamp, awaiting a re-run (issue 56)")
    check_notebook(path)


def declared_headlines(path: Path) -> set[str]:
    """The experiments whose headline (the front door's or a chapter's) ``path``'s notebook holds."""
    from wmthesis.headline import CHAPTER_ROWS, HEADLINES

    return {h.experiment for h in HEADLINES + CHAPTER_ROWS if path.stem.startswith(f"{h.notebook}_")}


def missing_headlines(path: Path, outputs: str) -> set[str]:
    """The declared headlines of ``path`` for which ``outputs`` print no headline line."""
    return declared_headlines(path) - {line["experiment"] for line in HEADLINE_LINE.finditer(outputs)}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_a_committed_notebook_s_headline_numbers_are_the_summary_s(path):
    summary = json.loads((ROOT / "data" / "results" / "summary.json").read_text())["rows"]
    rows = {(r["experiment"], variant_label(r["experiment"], r["variant"]), r["profile"]): r for r in summary}
    outputs = "\n".join(output_text(cell) for cell in code_cells(path))
    assert not missing_headlines(path, outputs), f"{path.name}: declares {missing_headlines(path, outputs)} and prints no headline line for it"
    for cell in code_cells(path):
        for line in HEADLINE_LINE.finditer(output_text(cell)):
            key = (line["experiment"], line["variant"], line["profile"])
            assert key in rows, f"{path.name}: {line[0]!r} has no row in summary.json"
            row = rows[key]
            assert (float(line["mean"]), int(line["n"]), list(map(int, line["seeds"].split()))) == \
                (round(row["mean"], 1), row["n"], row["seeds"]), f"{path.name}: {line[0]!r} is not the summary's row"


def test_the_check_refuses_a_notebook_run_out_of_order_on_changed_code_or_unstamped(tmp_path):
    def notebook(counts, last_output):
        cells = [{"cell_type": "code", "execution_count": n, "source": "", "metadata": {},
                  "outputs": [{"output_type": "stream", "name": "stdout", "text": last_output if i == len(counts) - 1
                               else ""}]} for i, n in enumerate(counts)]
        path = tmp_path / "n.ipynb"
        path.write_text(json.dumps({"cells": cells}))
        return path

    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    if not head:
        pytest.skip("not a git checkout")
    good = stamp("quick", time.time() - 3).replace(git_commit(), head)
    check_notebook(notebook([1, 2], good))
    with pytest.raises(AssertionError, match="top to bottom"):
        check_notebook(notebook([2, 1], good))
    with pytest.raises(AssertionError, match="no run stamp"):
        check_notebook(notebook([1, 2], "wall time 3 s"))
    with pytest.raises(AssertionError, match="differed from commit"):
        check_notebook(notebook([1, 2], good.replace(head, head + "+changes")))
    with pytest.raises(AssertionError, match="not in the history"):
        check_notebook(notebook([1, 2], good.replace(head, "0000000")))
    with pytest.raises(AssertionError, match="quick's, not smoke's"):
        check_notebook(notebook([1, 2], good.replace("profile quick", "profile smoke")))


def test_a_stamp_reads_back():
    line = stamp("smoke", time.time() - 4)
    found = read_stamp("noise\n" + line + "\n")
    assert found["profile"] == "smoke" and found["commit"] + ("+changes" if found["changes"] else "") == git_commit()
    assert 4 <= found["seconds"] <= 60 and found["threads"] >= 1 and "cores" in found["cpu"]
    assert read_stamp("nothing here") is None


def test_the_index_reads_each_notebooks_stamp_and_names_one_it_does_not_know(tmp_path):
    from wmthesis.notebook_index import SHOWS, notebook_rows, notebook_table

    def write(name: str, last_output: str) -> None:
        cells = [{"cell_type": "code", "execution_count": 1, "metadata": {}, "source": "print(1)",
                  "outputs": [{"output_type": "stream", "name": "stdout", "text": last_output}]}]
        (tmp_path / f"{name}.ipynb").write_text(json.dumps({"cells": cells, "metadata": {}, "nbformat": 4,
                                                             "nbformat_minor": 5}))

    write("02_boxing_world_models", stamp("quick", time.time() - 1500, train=False) + "\n")
    write("03_boxing_world_models_alphazero", "no stamp here\n")
    rows = notebook_rows(tmp_path)
    assert [r["stamp"]["how"] if r["stamp"] else None for r in rows] == ["from shipped runs", None]
    table = notebook_table(rows)
    assert f"| `02_boxing_world_models` | 5.4.1 | {SHOWS['02_boxing_world_models'][1]} | 25 min from the shipped runs" in table
    assert "| awaiting a re-run on today's code |" in table.splitlines()[-1]
    write("12_new", stamp("quick", time.time(), train=True))
    with pytest.raises(ValueError, match="12_new.ipynb: not in wmthesis.notebook_index.SHOWS"):
        notebook_rows(tmp_path)


def test_a_notebooks_time_from_scratch_sums_its_runs_measured_first_runs(tmp_path):
    from wmthesis.notebook_index import TRAINS, notebook_table, scratch

    def write(path: Path, data: dict) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data))

    results = tmp_path / "results"  # a data folder of its own
    assert [e for e, _, _ in TRAINS["07_sokoban_search"]] == ["sokoban-search"]
    # seed 0: resumed later (its first run counts) and searched 1000 levels of two kinds
    write(results / "sokoban-search/quick-seed0/metrics.json", {"wall_seconds": 5.0, "first_run_wall_seconds": 600.0})
    write(results / "sokoban-search/quick-seed0/boxoban-report-1000.json",
          {"levels": 1000, "training_wall_seconds": 600.0,
           "rows": {"unfiltered": {"seconds_per_level": 0.5}, "medium": {"seconds_per_level": 1.5}}})
    # seed 1: its agent ships with its report alone (its training time is the report's)
    write(results / "sokoban-search/quick-seed1/boxoban-report-1000.json",
          {"levels": 1000, "training_wall_seconds": 1200.0, "rows": {"medium": {"seconds_per_level": 0.3}}})
    found = scratch("07_sokoban_search", tmp_path)  # seed 2 has not run
    assert found["seconds"] == 600.0 + 2000.0 + 1200.0 + 300.0
    assert (found["runs"], found["missing"]) == (2, [("sokoban-search", None, 2)])
    assert scratch("11_planning_budget", tmp_path)["missing"]  # a notebook's runs not made yet are named
    write(results / "sokoban-wm/quick-seed0/metrics.json", {"wall_seconds": 60.0, "first_run_wall_seconds": 1020.0})
    assert scratch("01_sokoban_world_models", tmp_path)["seconds"] == 1020.0  # opened, it reads its committed run
    row = {"name": "07_sokoban_search", "section": "x", "shows": "y", "stamp": None, "scratch": found}
    assert notebook_table([row]).endswith("| awaiting a re-run on today's code | 68 min over 2 runs, 1 not run yet |")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_notebook_has_a_parameters_cell_that_sets_the_profile(path):
    tagged = [c for c in json.loads(path.read_text())["cells"] if "parameters" in c["metadata"].get("tags", [])]
    assert len(tagged) == 1 and "PROFILE = " in "".join(tagged[0]["source"]), f"{path.name}: tag its parameters cell"


LAB_TALK = re.compile(r"\b(issues?|sessions?) \d+", re.I)
MACHINE_PATH = re.compile(r"(?<![\w.])/(work|home|tmp|Users|root|var)/")
NOISE = ("TqdmWarning", "IProgress not found", "A.L.E: Arcade Learning Environment", "Powered by Stella")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_a_committed_notebook_speaks_to_a_reader(path):
    """No placeholder where a figure or number should be, no work-log numbers, no paths of the
    machine that ran it, no warnings a reader should not care about."""
    cells = json.loads(path.read_text())["cells"]
    outputs = "\n".join(output_text(c) for c in cells if c["cell_type"] == "code")
    prose = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")
    assert "TRAIN = True" not in outputs, f"{path.name}: an output says it needs training"
    for text, where in ((prose, "prose"), (outputs, "outputs")):
        found = LAB_TALK.search(text)
        assert found is None, f"{path.name}: work-log number {found and found.group(0)!r} in its {where}"
    found = MACHINE_PATH.search(outputs)
    assert found is None, f"{path.name}: a machine path in its outputs: {outputs[max(0, found.start() - 40):found.end() + 40]!r}" \
        if found else ""
    assert not [n for n in NOISE if n in outputs], f"{path.name}: {[n for n in NOISE if n in outputs]} in its outputs"


def test_the_reader_check_fails_a_notebook_with_lab_talk_or_a_placeholder(tmp_path):
    notebook = {"cells": [{"cell_type": "markdown", "source": ["as issue 12 asked"]},
                          {"cell_type": "code", "source": [], "outputs": [{"text": "(needs TRAIN = True)"}]}]}
    (tmp_path / "x.ipynb").write_text(json.dumps(notebook))
    with pytest.raises(AssertionError, match="needs training"):
        test_a_committed_notebook_speaks_to_a_reader(tmp_path / "x.ipynb")
    notebook["cells"][1]["outputs"] = [{"text": "saved in /work/main/data"}]
    (tmp_path / "x.ipynb").write_text(json.dumps(notebook))
    with pytest.raises(AssertionError, match="work-log number 'issue 12'"):
        test_a_committed_notebook_speaks_to_a_reader(tmp_path / "x.ipynb")
    notebook["cells"][0]["source"] = ["plain prose"]
    (tmp_path / "x.ipynb").write_text(json.dumps(notebook))
    with pytest.raises(AssertionError, match="machine path"):
        test_a_committed_notebook_speaks_to_a_reader(tmp_path / "x.ipynb")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_notebook_opens_as_a_chapter(path):
    """Within its first cells, a box with the thesis's claim and the verdict on ours: written in its
    opening prose, or printed by its first code cells (:func:`wmthesis.chapters.chapter_box`)."""
    cells = json.loads(path.read_text())["cells"][:5]
    shown = "\n".join("".join(c["source"]) if c["cell_type"] == "markdown" else output_text(c) for c in cells)
    assert "**The thesis:**" in shown and "**Verdict**" in shown, f"{path.name}: no opening box in its first cells"


def test_a_chapters_box_prints_the_summarys_verdict():
    from wmthesis.chapters import chapter_box
    from wmthesis.headline import CHAPTER_ROWS, HEADLINES, judge

    bar = next(h for h in HEADLINES if h.experiment == "boxing-wm")  # the thesis: above 18
    assert judge(bar, None) == "not run yet"
    judged = next(h for h in CHAPTER_ROWS if h.notebook == "04")
    row = {"mean": -11.5, "ci_low": -12.0, "ci_high": -11.0, "n": 3, "wall_seconds": [60.0] * 3}
    assert judge(judged, row) == "reproduced (by eye, over 3 seeds)"
    one = {**row, "ci_low": None, "ci_high": None, "n": 1, "wall_seconds": [3600.0], "experiment": "planet-sokoban",
           "variant": "unchanged", "profile": "quick"}  # the eye alone settles nothing
    assert judge(judged, one) == ("not settled at 1 seed (one seed gives no interval; by eye on its figure: "
                                  "reproduced); 4 more seeds cost about 4.0 h of one core")
    box = chapter_box("04", folder=ROOT / "data" / "results")  # a chapter row opens its notebook
    assert "**PlaNet on Sokoban-small" in box and ("**Verdict**: not settled at " in box or
                                                   "**Verdict**: reproduced (by eye, over " in box)
    box = chapter_box("02", folder=ROOT / "data" / "results")
    assert "**Verdict** on the claim \"above 18\": reproduced." in box and "*The verdict's rule:*" in box
    with pytest.raises(ValueError, match="holds no headline; those that do: 01, 02, 03, 04, 05, 06, 07, 08, 09, 10"):
        chapter_box("00", folder=ROOT / "data" / "results")


def test_a_notebook_that_declares_a_headline_and_prints_none_fails(tmp_path):
    path = tmp_path / "02_boxing_world_models.ipynb"  # notebook 02 holds World Models on Boxing's headline
    assert declared_headlines(path) == {"boxing-wm"}
    assert missing_headlines(path, "seed 0: 42.2") == {"boxing-wm"}
    assert not missing_headlines(path, "headline · boxing-wm · separable-64 · quick: 34.4 [28.9, 40.0] over 10 seeds (0 1)")
    assert declared_headlines(tmp_path / "00_environments.ipynb") == set()  # the setting: no headline


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_notebook_closes_with_what_it_means_for_the_next_chapter(path):
    """Its last prose section says what the chapter means for what follows."""
    prose = [("".join(c["source"])) for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "markdown"]
    assert re.search(r"^## .*(next chapter|what comes next|What this means)", prose[-1], re.M | re.I), \
        f"{path.name}: its last section is not its closing one: {prose[-1][:80]!r}"
