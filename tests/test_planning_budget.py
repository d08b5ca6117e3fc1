"""Planning that pays (issue 57): the same agent with and without search, budget by budget."""
import csv

import numpy as np

from wmthesis.alphazero.variants import VARIANTS as ALPHAZERO
from wmthesis.envs.levels import parse_levels
from wmthesis.runs import read_json
from wmthesis.sokoban_search.agent import SearchAgent
from wmthesis.sokoban_search.budget import greedy_play
from wmthesis.sokoban_search.search import Simulator, best_first

LEVEL = parse_levels("""; 1
####
# .#
#  ###
#*@  #
#  $ #
#  ###
####
""")[0]


def steps_to_go(states: np.ndarray) -> np.ndarray:
    """A test-only oracle: each state's shortest solution in the true rules (0 when solved)."""
    plans = [best_first(Simulator().expand, s, budget=20_000).actions for s in states]
    return np.array([99 if plan is None else len(plan) for plan in plans])


def test_without_search_the_agent_follows_its_value_one_step_at_a_time():
    oracle = SearchAgent(Simulator(), heuristic=steps_to_go)
    shortest = len(best_first(Simulator().expand, LEVEL[1:-1, 1:-1], budget=20_000).actions)
    play = greedy_play(oracle, LEVEL)
    assert play["solved"] and play["steps"] == shortest and play["expanded"] == 0
    blind = greedy_play(SearchAgent(Simulator()), LEVEL, max_steps=30)  # no value: the first new state each step
    assert not blind["solved"] and blind["steps"] == 30


def test_a_smoke_curve_writes_each_budget_on_the_same_levels_and_resumes_with_nothing_to_do(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    from wmthesis.experiments import reproduce
    from wmthesis.budget_curves import COLUMNS
    from wmthesis.experiments.planning_budget import curve_sizes

    sizes = curve_sizes("smoke")

    metrics = reproduce("planning-budget", "smoke", 0, progress=False)
    rows = metrics["rows"]
    sokoban, mcts, cem = ([r for r in rows if r["planner"] == planner] for planner in ("sokoban-search", "mcts", "cem"))
    assert [r["budget"] for r in sokoban] == [0, *sizes.sokoban_budgets]
    assert [r["budget"] for r in mcts] == [0, *sizes.mcts_budgets]
    assert [r["budget"] for r in cem] == [0, *(h * j * i for h, j, i in sizes.cem_budgets)]  # H x J x I
    assert all(r["levels"] == sizes.boxing_bouts for r in cem)
    assert all(r["levels"] == sizes.sokoban_levels and 0 <= r["score"] <= 100 for r in sokoban)
    assert all(r["levels"] == sizes.boxing_bouts for r in mcts)
    for curve in (sokoban, mcts, cem):  # every budget on the same bouts or levels as the row without search
        assert all(r["no_search_score"] == curve[0]["score"] and r["ms_per_action"] > 0 for r in curve)
        assert all(abs(r["gain"] - (r["score"] - r["no_search_score"])) < 1e-9 for r in curve)
    with open(tmp_path / "results" / "planning_budget-smoke.csv") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == COLUMNS == ("planner", "game", "budget", "seed", "score", "no_search_score",
                                          "ms_per_action", "search", "changed", "return_changed", "return_kept")
    for row in mcts[1:]:  # where the search moved the head's action, read from its games
        assert 0 <= row["changed"] <= 1 and row["search"] == "puct tie_break=prior"
        assert (row["return_changed"] is not None) == (row["changed"] > 0)
    assert [(r["planner"], r["game"], int(r["budget"])) for r in table] == \
        [("cem", "boxing", r["budget"]) for r in cem] + [("mcts", "boxing", b) for b in (0, *sizes.mcts_budgets)] + \
        [("sokoban-search", "boxoban-medium", b) for b in (0, *sizes.sokoban_budgets)]
    saved = sorted((tmp_path / "smoke" / "planning-budget" / "seed0").glob("budget-*.json"))
    saved += sorted((tmp_path / "smoke" / "planning-budget" / "seed0").glob("evaluation-own-*.pkl"),
                    key=lambda p: int(p.name.split("-")[2]))
    assert len(saved) == 2 * len(sokoban) + len(sizes.mcts_budgets)  # Sokoban's budgets in two parts each
    stamps = [p.stat().st_mtime_ns for p in saved]
    again = reproduce("planning-budget", "smoke", 0, progress=False)
    assert again["rows"] == rows and [p.stat().st_mtime_ns for p in saved] == stamps

    # a budget cut off after its first game plays only the rest; one planner's new budgets keep the others' rows
    import wmthesis.alphazero.evaluation as evaluation
    from wmthesis.__main__ import main
    from wmthesis.alphazero.config import AlphaZeroConfig
    from wmthesis.alphazero.replay import game_seeds
    from wmthesis.config import for_profile
    from wmthesis.envs.atari import noop_count
    from wmthesis.experiments.planning_budget import curve_sizes
    from wmthesis.utils import read_pickle

    last = saved[-1]  # the top MCTS budget's games
    games = read_pickle(last)
    evaluation.save_games(last.with_name(last.stem + ".partial.pkl"), games["key"], games["games"][:1])
    last.unlink()
    played, real_play = [], evaluation.play
    monkeypatch.setattr(evaluation, "play", lambda *a, **k: played.append(a[3]) or real_play(*a, **k))
    assert main(["budget-curve", "mcts", "--budgets", f"{curve_sizes('smoke').mcts_budgets[-1]},3", "--profile", "smoke"]) == 0
    assert played == [*range(1, sizes.boxing_bouts), *range(sizes.boxing_bouts)]  # the cut budget's rest, then 3's
    after = {(r["planner"], r["budget"]): r for r in read_json(tmp_path / "results" / "planning-budget" / "smoke-seed0"
                                                                / "metrics.json")["rows"]}
    assert [b for p, b in after if p == "mcts"] == [0, sizes.mcts_budgets[-1], 3]
    assert after[("mcts", sizes.mcts_budgets[-1])]["score"] == mcts[-1]["score"]  # the resumed games score the same
    assert [after[(r["planner"], r["budget"])]["score"] for r in sokoban + cem] == [r["score"] for r in sokoban + cem]

    # the validation bouts: games the evaluation never plays, written apart from the report's rows
    report = (tmp_path / "results" / "planning_budget-smoke.csv").read_text()
    assert main(["budget-curve", "mcts", "--validation", "--profile", "smoke"]) == 0
    validation = read_json(tmp_path / "results" / "planning-budget" / "smoke-seed0" /
                           f"validation-{ALPHAZERO.default.name}.json")
    assert validation["variant"] == ALPHAZERO.default.name and validation["bouts"] == "validation"
    assert [r["budget"] for r in validation["rows"]] == [0, *sizes.mcts_budgets]
    assert main(["budget-curve", "mcts", "--validation", "--profile", "smoke", "--budgets", "3"]) == 0  # one more
    grown = read_json(tmp_path / "results" / "planning-budget" / "smoke-seed0" / f"validation-{ALPHAZERO.default.name}.json")
    assert [r["budget"] for r in grown["rows"]] == sorted([0, 3, *sizes.mcts_budgets])  # the earlier budgets kept
    assert [r for r in grown["rows"] if r["budget"] != 3] == validation["rows"]
    work = tmp_path / "smoke" / "planning-budget" / "seed0"
    budget = sizes.mcts_budgets[0]
    noop_max = for_profile(AlphaZeroConfig, "smoke").noop_max  # 3 counts: 2 evaluation bouts leave 1 to validate on
    counts = {split: [noop_count(game_seeds(s)[0], noop_max) for s in read_pickle(
        next(work.glob(f"{split}-own-{budget}-*.pkl")))["key"]["seeds"]] for split in ("evaluation", "validation")}
    assert len(counts["evaluation"]) == 2 and len(counts["validation"]) == 1
    assert not set(counts["validation"]) & set(counts["evaluation"])
    assert (tmp_path / "results" / "planning_budget-smoke.csv").read_text() == report
    assert read_json(tmp_path / "results" / "planning-budget" / "smoke-seed0" / "metrics.json")["rows"] == \
        list(after.values())
    assert main(["budget-curve", "cem", "--validation", "--profile", "smoke"]) == 2

    # another root on the same validation bouts: its own file, its own games, the same head alone
    assert main(["budget-curve", "mcts", "--validation", "--profile", "smoke", "--search", "root=gumbel,c_scale=0.05"]) == 0
    gumbel = read_json(tmp_path / "results" / "planning-budget" / "smoke-seed0" /
                       f"validation-{ALPHAZERO.default.name}-gumbel-c_scale=0.05.json")["rows"]
    assert [r["search"] for r in gumbel] == ["gumbel c_scale=0.05"] * (1 + len(sizes.mcts_budgets))
    assert gumbel[0]["score"] == validation["rows"][0]["score"]
    assert len(list(work.glob(f"validation-gumbel-{budget}-*.pkl"))) == 1


def test_bad_planners_and_budgets_are_refused_in_one_line_before_anything_plays(capsys):
    from wmthesis.__main__ import main
    from wmthesis.budget_curves import parse_budgets

    assert parse_budgets("mcts", "16, 64,16") == (16, 64) and parse_budgets("cem", "6x100x3,2X10x1") == ((6, 100, 3), (2, 10, 1))
    for argv, words in [(["chess"], "unknown planner 'chess'"), (["mcts", "--budgets", "0"], "budget 0 is the row without"),
                        (["mcts", "--budgets", "16,-4"], "'-4' is negative"), (["sokoban-search", "--budgets", "1e3"], "not an integer"),
                        (["cem", "--budgets", "1x100x3"], "horizon 1 is the value alone"), (["cem", "--budgets", "6x100"], "not HxJxI"),
                        (["cem", "--budgets", "6x0x3"], "has a 0"), (["mcts", "--variant", "own-memory"], "with --validation"),
                        (["mcts", "--validation", "--variant", "chess"], "unknown variant 'chess'"),
                        (["mcts", "--search", "root=gumbel"], "with --validation"),
                        (["mcts", "--validation", "--search", "root=chess"], "unknown root 'chess'"),
                        (["mcts", "--validation", "--search", "depth=3"], "is not NAME=VALUE"),
                        (["mcts", "--validation", "--search", "root=gumbel,c_scale=0"], "c_scale='0': it must be a finite number above 0")]:
        assert main(["budget-curve", *argv, "--profile", "smoke"]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err


def test_the_summary_tables_the_budget_rows_over_seeds_paired_with_no_search(tmp_path):
    from wmthesis.budget_curves import COLUMNS
    from wmthesis.summary import write_summary

    rows = [("mcts", "boxing", 0, 0, 30.0, 30.0, 2.0), ("mcts", "boxing", 0, 1, 20.0, 20.0, 2.0),
            ("mcts", "boxing", 64, 0, 36.0, 30.0, 9.0), ("mcts", "boxing", 64, 1, 22.0, 20.0, 11.0)]
    with open(tmp_path / "planning_budget.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        writer.writerows(rows)
    write_summary(tmp_path)
    table = (tmp_path / "summary.md").read_text().split("## Score against search budget")[1]
    # by hand: gains 6 and 2, mean 4, sample std 2.8284, t_{0.975, 1} = 12.706: half width 25.4
    assert "| mcts | boxing | 0 | 2 | 25.0 | +0.0 [+0.0, +0.0] | 2.0 |" in table
    assert "| mcts | boxing | 64 | 2 | 29.0 | +4.0 [-21.4, +29.4] | 10.0 |" in table


def test_a_fresh_clone_plays_cems_budgets_on_the_shipped_agents_to_the_same_scores(tmp_path, monkeypatch):
    """Where the value run's checkpoint is not here but its agent file and metrics are (a fresh
    clone), CEM's budget curve plays the shipped value on the shipped PlaNet model: no PlaNet
    training, no value fit, and the scores of the run that fitted it."""
    import pytest

    import wmthesis.runs as run_store
    from wmthesis.experiments import reproduce
    from wmthesis.experiments.planning_budget import cem_curve

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path / "trained"))
    reproduce("planet-boxing-value", "smoke", 0, progress=False)
    trained = cem_curve("smoke", 0, progress=False, budgets=((2, 16, 2),))  # one budget beside the value alone
    clone = tmp_path / "clone"
    for part in ("smoke/planet-boxing-agent/seed0/agent.pt", "results/planet-boxing-agent/smoke-seed0/metrics.json",
                 "smoke/planet-boxing-value/lean-value-rewards-0.7-seed0/agent.pt",
                 "results/planet-boxing-value/smoke-seed0/lean-value-rewards-0.7/metrics.json"):
        (clone / part).parent.mkdir(parents=True)
        (clone / part).write_bytes((tmp_path / "trained" / part).read_bytes())
    monkeypatch.setenv("WMTHESIS_DATA", str(clone))
    monkeypatch.setattr(run_store, "built_on", lambda *args, **kwargs: pytest.fail("trained or fitted again"))
    cloned = cem_curve("smoke", 0, progress=False, budgets=((2, 16, 2),))
    assert [(r["budget"], r["score"], r["no_search_score"]) for r in cloned] == \
        [(r["budget"], r["score"], r["no_search_score"]) for r in trained]
    assert not (clone / "smoke" / "planet-boxing-value" / "lean-value-rewards-0.7-seed0" / "value.pt").exists()


def test_cems_budget_counts_every_imagined_path_of_a_planner_with_particles(tmp_path, monkeypatch):
    """A budget is the imagined steps an action: H x J x I, times K where each candidate is the mean
    of K imagined paths; the row without search stays 0."""
    import dataclasses
    import importlib

    from wmthesis.value.config import ValuePlannerConfig

    planning_budget = importlib.import_module("wmthesis.experiments.planning_budget")  # the module, not its recipe
    played = {}

    def scores(planet_run, work, metrics, planners, bouts, progress, folder):
        played.update(planners)
        return {name: {"returns": [1.0, 2.0], "ms_per_action": 1.0} for name in planners}

    config = dataclasses.asdict(ValuePlannerConfig(rewards="value", particles=4))
    monkeypatch.setattr(planning_budget, "frozen_agent", lambda *a, **k: ({"value_planner": {"config": config},
                                                                            "bouts": [[0, 0], [1, 1]]}, tmp_path))
    monkeypatch.setattr(planning_budget, "lever_scores", scores)
    rows = planning_budget.cem_curve("smoke", 0, progress=False, budgets=((2, 16, 2), (3, 10, 1)))
    assert [r["budget"] for r in rows] == [0, 2 * 16 * 2 * 4, 3 * 10 * 1 * 4]
    assert [(p.horizon, p.candidates, p.particles) for p in played.values()] == [(1, None, 4), (2, 16, 4), (3, 10, 4)]


def test_where_mcts_moved_its_head_is_tabled_per_budget_over_seeds():
    from wmthesis.budget_curves import changes_markdown

    base = dict(planner="mcts", game="boxing", no_search_score=10.0, ms_per_action=1.0)
    rows = [dict(base, budget=0, seed=0, score=10.0, changed=None, return_changed=None, return_kept=None),
            dict(base, budget=4, seed=0, score=14.0, changed=0.1, return_changed=0.3, return_kept=0.1),
            dict(base, budget=4, seed=1, score=8.0, changed=0.3, return_changed=None, return_kept=0.2),
            dict(base, planner="cem", budget=600, seed=0, score=1.0)]
    lines = changes_markdown(rows).splitlines()
    assert len(lines) == 3 and lines[2] == "| 4 | 2 | 20.0% | +0.300 | +0.150 | +1.0 |"
    assert changes_markdown(rows[3:]) == ""


def test_a_kept_value_signal_is_read_only_for_the_models_and_measurement_it_was_made_on(tmp_path, monkeypatch):
    import pytest

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    from wmthesis.value.signal import SIGNAL_BOUTS, SIGNAL_DEPTHS, SIGNAL_VERSION, seed_value_signal, signal_models
    from wmthesis.runs import results_folder, write_json

    kept = {"version": SIGNAL_VERSION, "models": signal_models("quick", 7), "depths": list(SIGNAL_DEPTHS),
            "bouts": SIGNAL_BOUTS, "correlation": {str(d): 0.1 * d for d in SIGNAL_DEPTHS}}
    path = write_json(results_folder("planning-budget", "quick", 7) / "value_signal.json", kept)
    assert seed_value_signal("quick", 7) == {d: 0.1 * d for d in SIGNAL_DEPTHS}
    for changed in ({"models": {"planet-boxing-agent": "another model", "planet-boxing-value": None}},
                    {"version": SIGNAL_VERSION + 1}):
        write_json(path, {**kept, **changed})
        with pytest.raises(FileNotFoundError, match="no fitted value for seed 7"):  # measured again: nothing to measure here
            seed_value_signal("quick", 7)


def test_the_chapters_box_gives_each_curve_its_largest_budgets_gain_and_verdict():
    from wmthesis.budget_curves import budget_box

    def row(planner, budget, seed, score, base):
        return {"planner": planner, "game": "g", "budget": budget, "seed": seed, "score": score,
                "no_search_score": base, "ms_per_action": 1.0}

    rows = [row("mcts", b, s, base + gain * (b > 0), base) for s, base in ((0, 10.0), (1, 20.0), (2, 30.0))
            for b, gain in ((0, 0), (4, -1.0 + s), (64, 5.0 + s))]  # at 64: gains 5, 6, 7
    rows += [row("cem", b, s, base - 2.0 * (b > 0) + s * (b > 0), base) for s, base in ((0, 1.0), (1, 2.0))
             for b in (0, 300)]  # gains -2, -1 on 2 seeds: an interval holding 0
    rows += [row("sokoban-search", b, 0, 50.0 + 40 * (b > 0), 50.0) for b in (0, 1000)]  # one seed: no interval
    box = budget_box(rows, "quick").splitlines()
    assert box[1].startswith("> **The thesis:** \"planning carries the promise")
    assert box[2].startswith("> **Learned from:** no steps of its own")
    box = box[:2] + box[3:]  # each planner's line follows
    # by hand: mean 6, sample std 1, t_{0.975, 2} = 4.303: half width 2.48
    assert "mcts on g: 26.0 at budget 64, +6.0 [+3.5, +8.5] over no search on the same bouts or levels (3 seeds); " \
           "**Verdict** on the claim \"a gain above 0\", by budget: not settled at 3 seeds (the interval holds both " \
           "the claim and its denial) at 4; not settled at 3 seeds (beyond needs 5 seeds" in box[2]
    assert "-1.5 [" in box[3] and box[3].endswith("by budget: not settled at 2 seeds (the interval holds both the claim "
                                                  "and its denial) at 300  ")
    assert "sokoban-search on g: 90.0 at budget 1,000, +40.0 over no search" in box[4] and \
        "not settled at 1 seed (one seed gives no interval) at 1,000" in box[4]
    hurt = [row("mcts", b, s, 10.0 - 3.0 * (b > 0) - 0.1 * s * (b > 0), 10.0) for s in (0, 1, 2) for b in (0, 8)]
    assert "by budget: not reproduced at 8" in budget_box(hurt)
    five = [row("mcts", b, s, 10.0 + (6.0 + 0.1 * s) * (b > 0), 10.0) for s in range(5) for b in (0, 8)]
    assert "by budget: beyond at 8" in budget_box(five)
