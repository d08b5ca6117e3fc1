"""The one house: variants declared one way, the run store, published figures written once, and
the rules the package keeps (no module imports another's underscore names, no recipe imports a
sibling recipe, no file over 450 lines)."""
from __future__ import annotations

import ast
import json
import os
import shutil
import warnings
from pathlib import Path

import pytest

from wmthesis.experiments import EXPERIMENTS, NO_VARIANTS, RECIPES, VARIANTS, reproduce
from wmthesis.references import Reference, human, published, published_figures
from wmthesis.runs import built_on, read_json, results_folder, work_folder, write_json
from wmthesis.summary import read_runs
from wmthesis.variants import Variant, Variants

PACKAGE = Path(__file__).resolve().parents[1] / "wmthesis"


def test_a_registry_holds_one_default_and_merges_changes_along_what_a_variant_builds_on():
    registry = Variants("demo", Variant("base", "the default", dict(value=dict(rounds=5)), default=True),
                        Variant("more", "more rounds", dict(value=dict(rounds=10), planner=dict(horizon=2)),
                                builds_on="base"),
                        Variant("lean", "lean", dict(value=dict(score=False)), builds_on="more"))
    assert registry.default.name == "base" and registry.check(None) is registry.default
    assert registry.changes("lean") == {"value": {"rounds": 10, "score": False}, "planner": {"horizon": 2}}
    assert registry.changes("lean", "value") == {"rounds": 10, "score": False}
    assert [v.name for v in registry.lineage("lean")] == ["base", "more", "lean"]
    assert registry.rows()[1] == ["more", "ablation", "base", "more rounds"]
    with pytest.raises(ValueError, match=r"unknown variant 'gone' of demo; valid: base, more, lean .*docs/findings/demo.md"):
        registry.check("gone")
    with pytest.raises(ValueError, match="exactly one default"):
        Variants("demo", Variant("a", "a"), Variant("b", "b"))
    with pytest.raises(ValueError, match="declared twice"):
        Variants("demo", Variant("a", "a", default=True), Variant("a", "again"))
    with pytest.raises(ValueError, match="builds on 'nowhere'"):
        Variants("demo", Variant("a", "a", default=True), Variant("b", "b", builds_on="nowhere"))
    rooted = Variants("demo", Variant("first", "the first recipe"), Variant("better", "b", default=True), root="first")
    assert rooted.folder_name("first") is None and rooted.folder_name(None) == rooted.folder_name("better") == "better"
    with pytest.raises(ValueError, match="the root 'gone' is not declared"):
        Variants("demo", Variant("a", "a", default=True), root="gone")


def test_every_experiment_has_one_recipe_signature_and_refuses_a_variant_it_lacks():
    assert tuple(RECIPES) == EXPERIMENTS and set(NO_VARIANTS) | set(VARIANTS) == set(EXPERIMENTS)
    for name, registry in VARIANTS.items():  # the file a refusal names is there
        assert registry.experiment == name and Path(PACKAGE.parent, registry.findings).is_file(), name
    for name in NO_VARIANTS:  # refused before anything runs
        with pytest.raises(ValueError, match="has no variants"):
            RECIPES[name]("smoke", 0, "anything", False)
    with pytest.raises(ValueError, match="docs/findings/planet-boxing-value.md"):
        reproduce("planet-boxing-value", "smoke", 0, "td")  # removed: its numbers went to the findings


def test_the_run_store_names_folders_one_way_and_says_what_a_missing_run_needs(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    assert work_folder("quick", "planet-freeway", 3, "freeway-adam") == tmp_path / "quick/planet-freeway/freeway-adam-seed3"
    assert results_folder("boxing-wm", "quick", 3) == tmp_path / "results/boxing-wm/quick-seed3"
    import wmthesis.experiments as experiments

    asked = []
    monkeypatch.setattr(experiments, "RECIPES", {**experiments.RECIPES, "planet-boxing-agent":
                                                 lambda *args: asked.append(args) or {"score": 1.5}})
    assert built_on("planet-boxing-agent", "quick", 3) == {"score": 1.5}  # made through the package's reproduce
    assert asked == [("quick", 3, None, True)]
    path = write_json(results_folder("planet-boxing-agent", "quick", 3) / "metrics.json", {"score": 1.5})
    assert read_json(path) == {"score": 1.5}
    path.write_text("{not json")
    assert read_json(path) is None  # corrupt: computed again, never a traceback


def test_published_figures_are_written_once_and_shown_with_their_sources():
    assert human("boxing") == 12.1 and human("freeway") == 29.6
    assert published("boxing-wm")["thesis World Models"] == "above 18 on average across 5 runs"
    assert all(ref.source for name in EXPERIMENTS for ref in published_figures(name))
    assert published("planet-sokoban") == {}  # the thesis judged its model by eye (Fig. 58): no figure
    sources = [p for p in PACKAGE.rglob("*.py") if p.name != "references.py"]
    assert not [p for p in sources if "12.1" in p.read_text()]  # the human score, only in references.py


def test_the_summary_skips_a_removed_variants_folder_naming_it(tmp_path):
    kept = {"experiment": "planet-boxing-value", "variant": "lean", "profile": "quick", "seed": 0,
            "value": {"mean": 30.0}, "wall_seconds": 60}
    write_json(tmp_path / "planet-boxing-value/quick-seed0/lean/metrics.json", kept)
    write_json(tmp_path / "planet-boxing-value/quick-seed0/td/metrics.json", {**kept, "variant": "td"})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        runs = read_runs(tmp_path)
    assert [(r.variant, r.score) for r in runs] == [("lean", 30.0)]
    said = " ".join(str(w.message) for w in caught)
    assert "quick-seed0/td: skipped, written by variant 'td'" in said and "docs/findings/planet-boxing-value.md" in said


def _imports(path: Path):
    return [node for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.ImportFrom)
            and node.module and node.module.startswith("wmthesis")]


def test_no_module_imports_another_modules_underscore_names_and_no_recipe_a_sibling():
    underscore, sibling = [], []
    for path in PACKAGE.rglob("*.py"):
        module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        for node in _imports(path):
            underscore += [f"{path.name}: {node.module}.{a.name}" for a in node.names
                           if a.name.startswith("_") and node.module != module]
            if path.parent.name == "experiments" and path.name != "__init__.py" and ".experiments." in node.module:
                sibling.append(f"{path.name}: {node.module}")
    assert underscore == [] and sibling == []


def test_no_file_of_the_package_runs_over_450_lines_and_the_recipes_stay_thin():
    lengths = {str(p.relative_to(PACKAGE)): len(p.read_text().splitlines()) for p in PACKAGE.rglob("*.py")}
    assert {name: n for name, n in lengths.items() if n > 450} == {}
    assert sum(n for name, n in lengths.items() if name.startswith("experiments/")) <= 1950  # today's 1,944


def test_the_committed_results_of_kept_variants_still_read():
    results = PACKAGE.parent / "data" / "results"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no committed folder is skipped
        runs = read_runs(results)
    summary = json.loads((results / "summary.json").read_text())["rows"]
    assert {(r.experiment, r.variant) for r in runs} >= {(row["experiment"], row["variant"]) for row in summary}


def test_the_readme_holds_the_table_the_summary_writes_within_its_first_60_lines(tmp_path):
    from wmthesis.headline import BEGIN, END, headline_table, readme_with_table
    from wmthesis.summary import summarise

    readme = (PACKAGE.parent / "README.md").read_text()
    table = headline_table(summarise(read_runs(PACKAGE.parent / "data" / "results")))
    assert f"{BEGIN}\n{table}\n{END}" in readme  # run `python -m wmthesis summary` after new results
    from wmthesis import notebook_index

    index = notebook_index.notebook_table(notebook_index.notebook_rows(data=PACKAGE.parent / "data"))
    assert f"{notebook_index.BEGIN}\n{index}\n{notebook_index.END}" in readme  # every notebook, its stamp's minutes
    assert readme.splitlines().index(END) < 60 and len(readme.splitlines()) <= 200
    from wmthesis.world_models.variants import BOXING_WM

    boxing = [r for r in summarise(read_runs(PACKAGE.parent / "data" / "results"))
              if (r["experiment"], r["variant"], r["profile"]) == ("boxing-wm", BOXING_WM.folder_name(None), "quick")]
    ours = "not run yet" if not boxing else (f"{boxing[0]['mean']:.1f}" + ("" if boxing[0]["n"] == 1 else
                                             f" [{boxing[0]['ci_low']:.1f}, {boxing[0]['ci_high']:.1f}]") +
                                             f" ({boxing[0]['n']} seed{'s' * (boxing[0]['n'] > 1)})")
    assert f"| {ours} |" in table.splitlines()[3]  # World Models on Boxing: its default's own row, to the digit
    with pytest.raises(ValueError, match="no results block"):
        readme_with_table("# a README without markers\n", table)


def test_every_declaration_resolves_and_names_only_declared_experiments():
    """Each experiment's one declaration: its recipe, variants, agent loader and score reader
    resolve; what it builds on is declared before it; the shipped agents' files are where it says."""
    from wmthesis.declarations import DECLARED as DECLARATIONS, EXPERIMENTS as DECLARED, resolve
    from wmthesis.agents import agent_file

    assert DECLARED == EXPERIMENTS and tuple(RECIPES) == DECLARED
    seen = set()
    for d in DECLARATIONS.values():
        assert callable(resolve(d.recipe)) and callable(resolve(d.score))
        assert set(d.builds_on) <= seen, d.name  # declared in order: what it builds on comes first
        assert (d.registry() is None) == (d.name not in VARIANTS)
        if d.agent is not None:
            assert callable(resolve(d.agent.loader))
        if d.published is not None:
            assert resolve(d.published) and all(isinstance(ref, Reference) for ref in resolve(d.published)), d.name
        if d.choice_seeds is not None:
            assert all(isinstance(s, int) for s in resolve(d.choice_seeds)), d.name
        assert d.bounds is None or d.bounds[0] < d.bounds[1]
        seen.add(d.name)
    shipped = Path(__file__).resolve().parents[1] / "data"
    for name in ("boxing-wm", "boxing-wm-alphazero", "planet-boxing-agent", "planet-boxing-value", "planet-freeway",
                 "sokoban-search"):
        relative = agent_file(name).relative_to(Path(os.environ["WMTHESIS_DATA"]))
        assert (shipped / relative).is_file(), relative


def test_the_summary_never_replaces_the_readmes_table_with_one_from_fewer_runs(tmp_path):
    from wmthesis.summary import write_summary

    readme = tmp_path / "README.md"
    readme.write_text((Path(__file__).resolve().parents[1] / "README.md").read_text())
    before = readme.read_text()
    empty = tmp_path / "results"
    empty.mkdir()
    with pytest.raises(ValueError, match="holds fewer runs than the README's table: it would drop .*World Models on Boxing"):
        write_summary(empty, readme)
    assert readme.read_text() == before and not (empty / "summary.md").exists()  # nothing written
    write_summary(empty, readme, force=True)
    assert "not run yet" in readme.read_text()
    readme.write_text(before)  # a folder with one seed fewer of World Models on Boxing
    fewer = tmp_path / "fewer"
    shutil.copytree(Path(__file__).resolve().parents[1] / "data" / "results", fewer)
    shutil.rmtree(fewer / "boxing-wm" / "quick-seed0")
    with pytest.raises(ValueError, match=r"it would drop World Models on Boxing \(10 -> 9 seeds\)"):
        write_summary(fewer, readme)
    assert readme.read_text() == before


def test_no_branch_on_an_experiments_name_outside_the_declarations():
    """What an experiment does differently is declared once (wmthesis/declarations.py), never
    tested for by its name elsewhere."""
    names = set(EXPERIMENTS)
    branches = []
    for path in PACKAGE.rglob("*.py"):
        if path.name == "declarations.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.If, ast.IfExp)) and any(_names_an_experiment(n, names) for n in ast.walk(node.test)):
                branches.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert branches == []


def _names_an_experiment(node: ast.AST, names: set[str]) -> bool:
    """``"boxing-wm"`` or ``NAMES.boxing_wm``."""
    return (isinstance(node, ast.Constant) and node.value in names) or (
        isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "NAMES")


def test_experiment_names_are_written_in_the_declarations_alone():
    """Every name is a field of ``NAMES``, and the package outside the declarations writes a name
    as text at most a few times (where it names something else too: the Sokoban planner)."""
    from wmthesis.declarations import NAMES

    assert set(vars(NAMES).values()) == set(EXPERIMENTS)
    assert all(getattr(NAMES, field) == value for field, value in vars(NAMES).items())
    names, written = set(EXPERIMENTS), []
    for path in PACKAGE.rglob("*.py"):
        if path.name != "declarations.py":
            written += [f"{path.relative_to(PACKAGE)}:{node.lineno}" for node in ast.walk(ast.parse(path.read_text()))
                        if isinstance(node, ast.Constant) and node.value in names]
    assert len(written) <= 3, written  # today's: the Sokoban planner's name among the planners and in its curve


def test_each_profiles_sizes_are_written_in_the_config_modules_alone():
    """Each profile's sizes belong in a config dataclass, overridden per profile in one place
    (wmthesis.config.OVERRIDES; PlaNet's per-game sizes in planet/profiles.py): no table keyed by
    profile and no test of a profile's name elsewhere."""
    from wmthesis.config import PROFILES

    tables, branches = [], []
    for path in PACKAGE.rglob("*.py"):
        if path.name in ("config.py", "profiles.py"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            where = f"{path.relative_to(PACKAGE)}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Dict) and node.keys and all(isinstance(k, ast.Constant) and k.value in PROFILES
                                                                  for k in node.keys):
                tables.append(where)
            if isinstance(node, ast.Compare) and any(isinstance(n, ast.Constant) and n.value in PROFILES
                                                     for n in [node.left, *node.comparators]):
                branches.append(where)
    assert tables == [] and branches == []


# The wings a wing may import, as the thesis builds them on one another: PlaNet's encoder and
# decoder are World Models' VAE networks (thesis 4.4.1), the AlphaZero coupling plans in the World
# Models memory (4.3), and the learned value is fitted on PlaNet's frozen model.
WINGS_BUILT_ON = {"world_models": set(), "sokoban_search": set(), "planet": {"world_models"},
                  "alphazero": {"world_models"}, "value": {"planet"}}


def test_a_wing_imports_only_the_wings_it_builds_on():
    crossing = []
    for wing, allowed in WINGS_BUILT_ON.items():
        for path in (PACKAGE / wing).rglob("*.py"):
            for node in _imports(path):
                other = node.module.split(".")[1] if node.module.count(".") else None
                if other in WINGS_BUILT_ON and other != wing and other not in allowed:
                    crossing.append(f"{wing}/{path.name} imports {node.module}")
    assert crossing == []
    assert set(WINGS_BUILT_ON) == {p.name for p in PACKAGE.iterdir() if (p / "config.py").is_file()}


def test_a_fresh_install_takes_the_locked_versions_the_numbers_were_made_with():
    """requirements.txt installs within constraints.txt (as .ci/run does), and what is installed
    here is what the lock says."""
    import importlib.metadata
    import re

    root = Path(__file__).resolve().parents[1]
    assert "-c constraints.txt" in (root / "requirements.txt").read_text().splitlines()
    assert "pip install --quiet -r requirements.txt" in (root / ".ci" / "run").read_text()
    locked = dict(re.findall(r"^([A-Za-z0-9_.-]+)==(\S+)", (root / "constraints.txt").read_text(), re.M))
    assert locked and {name: importlib.metadata.version(name) for name in locked} == locked


def test_the_suite_removes_the_data_folder_it_made(tmp_path):
    """A test run with no WMTHESIS_DATA of its own makes one in the temporary folder and removes it
    when it ends (they had piled up to gigabytes)."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k not in ("WMTHESIS_DATA", "PYTEST_XDIST_WORKER")}
    code = ("import os, pathlib; pathlib.Path(os.environ['WMTHESIS_DATA'], 'made').write_text('x'); "
            "print(os.environ['WMTHESIS_DATA'])")
    test = tmp_path / "test_one.py"
    test.write_text(f"def test_writes():\n    import subprocess, sys\n    exec({code!r})\n")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-s", "-n", "0", "-p", "no:cacheprovider",
                           "-p", "conftest", str(test)],  # the repository's conftest.py, for a test outside it
                          cwd=tmp_path, env={**env, "TMPDIR": str(tmp_path), "PYTHONPATH": str(root)},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    made = Path(next(line for line in done.stdout.splitlines() if "wmthesis-test-data-" in line).strip(". "))
    assert made.parent == tmp_path and not made.exists()
