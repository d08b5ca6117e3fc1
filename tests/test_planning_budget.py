"""Planning that pays (issue 57): the same agent with and without search, budget by budget."""
import csv

import numpy as np

from wmthesis.envs.levels import parse_levels
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
    from wmthesis.experiments.planning_budget import (BOXING_BOUTS, CEM_BUDGETS, MCTS_BUDGETS, SOKOBAN_BUDGETS,
                                                      SOKOBAN_LEVELS)

    metrics = reproduce("planning-budget", "smoke", 0, progress=False)
    rows = metrics["rows"]
    sokoban, mcts, cem = ([r for r in rows if r["planner"] == planner] for planner in ("sokoban-search", "mcts", "cem"))
    assert [r["budget"] for r in sokoban] == [0, *SOKOBAN_BUDGETS["smoke"]]
    assert [r["budget"] for r in mcts] == [0, *MCTS_BUDGETS["smoke"]]
    assert [r["budget"] for r in cem] == [0, *(h * j * i for h, j, i in CEM_BUDGETS["smoke"])]  # H x J x I
    assert all(r["levels"] == BOXING_BOUTS["smoke"] for r in cem)
    assert all(r["levels"] == SOKOBAN_LEVELS["smoke"] and 0 <= r["score"] <= 100 for r in sokoban)
    assert all(r["levels"] == BOXING_BOUTS["smoke"] for r in mcts)
    for curve in (sokoban, mcts, cem):  # every budget on the same bouts or levels as the row without search
        assert all(r["no_search_score"] == curve[0]["score"] and r["ms_per_action"] > 0 for r in curve)
        assert all(abs(r["gain"] - (r["score"] - r["no_search_score"])) < 1e-9 for r in curve)
    with open(tmp_path / "results" / "planning_budget-smoke.csv") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == COLUMNS == ("planner", "game", "budget", "seed", "score", "no_search_score",
                                          "ms_per_action")
    assert [(r["planner"], r["game"], int(r["budget"])) for r in table] == \
        [("cem", "boxing", r["budget"]) for r in cem] + [("mcts", "boxing", b) for b in (0, *MCTS_BUDGETS["smoke"])] + \
        [("sokoban-search", "boxoban-medium", b) for b in (0, *SOKOBAN_BUDGETS["smoke"])]
    saved = sorted((tmp_path / "smoke" / "planning-budget" / "seed0").glob("budget-*.json"))
    saved += sorted((tmp_path / "smoke" / "boxing-wm-alphazero" / "seed0" / "imitation").glob("*-simulations-*.pkl"))
    assert len(saved) == 2 * len(sokoban) + len(MCTS_BUDGETS["smoke"])  # Sokoban's budgets in two parts each
    stamps = [p.stat().st_mtime_ns for p in saved]
    again = reproduce("planning-budget", "smoke", 0, progress=False)
    assert again["rows"] == rows and [p.stat().st_mtime_ns for p in saved] == stamps
