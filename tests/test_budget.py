"""The real environment steps each run learned from: the readers on committed files, the summary
adding the runs an experiment builds on, and the front door's column."""
import json
from pathlib import Path

import numpy as np
import pytest

from wmthesis.budget import (FULL_BOUT, Steps, alphazero_steps, short, store_steps, value_steps,
                             world_models_steps)
from wmthesis.headline import agent_steps
from wmthesis.references import ATARI_100K, BOXOBAN, best_atari_100k
from wmthesis.summary import read_runs, summarise

RESULTS = Path(__file__).resolve().parents[1] / "data" / "results"


def read(path: str) -> dict:
    return json.loads((RESULTS / path).read_text())


@pytest.mark.parametrize("game", ["Boxing", "Freeway"])
def test_a_random_players_bout_lasts_the_full_bout(game):
    from wmthesis.envs.atari import make_atari

    env = make_atari(game)
    env.reset(seed=3)
    rng, steps, done = np.random.default_rng(3), 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        steps, done = steps + 1, terminated or truncated
    env.close()
    assert steps == FULL_BOUT[game.lower()]


def test_world_models_budget_is_its_random_rollouts_and_every_cma_es_bout():
    metrics = read("boxing-wm/quick-seed0/separable-64/metrics.json")
    steps = world_models_steps(metrics)
    assert steps.parts["random play"] == metrics["random_play_in_store"]["episodes"] * 1786
    assert steps.parts["CMA-ES"] == metrics["controller_curve"][-1]["agent_steps"]
    curve = metrics["controller_curve"]  # about 40 generations x 64 candidates x one bout
    assert 0.9 * len(curve) * 64 * 1786 < steps.parts["CMA-ES"] < 1.1 * len(curve) * 64 * 1786
    recorded = {**metrics, "random_play_in_store": {"episodes": 20, "steps": 35_000}}
    assert world_models_steps(recorded).parts["random play"] == 35_000 and not steps.at_most


def test_the_couplings_own_games_and_their_bound_where_a_file_kept_no_count():
    metrics = read("boxing-wm-alphazero/quick-seed3/own-memory/metrics.json")
    run = metrics["runs"]["own-memory"]
    steps = alphazero_steps(metrics)
    assert steps.parts["self-play"] == sum(g["steps"] for g in run["curve"]) == 100 * 400
    assert steps.parts["expert bouts imitated"] == run["expert"]["steps"]
    assert steps.at_most and steps.parts["expert bouts the memory learns"] == 20 * 1786
    counted = {**run, "memory_steps": 35_000, "tests": [{**t, "steps": 390} for t in run["tests"]]}
    exact = alphazero_steps({**metrics, "runs": {"own-memory": counted}})
    assert not exact.at_most and exact.parts["tests during self-play"] == 390 * len(run["tests"])
    assert exact.total == steps.total - 20 * 1786 + 35_000 - (400 - 390) * len(run["tests"])


def test_a_values_bouts_by_its_config():
    metrics = read("planet-boxing-value/quick-seed0/lean-value-rewards-0.7/metrics.json")
    config = metrics["config"]
    steps = value_steps(metrics)
    assert steps.parts["random bouts"] == config["random_bouts"] * 1786
    assert steps.parts["the value's bouts"] == config["rounds"] * config["bouts_per_round"] * 1786
    assert steps.parts["validation bouts"] == 0 and steps.at_most  # lean scores no round
    scored = value_steps({**metrics, "config": {**config, "score_rounds": True}})
    assert scored.parts["validation bouts"] == (config["rounds"] + 1) * config["validation_bouts"] * 1786
    freeway = value_steps(read("planet-freeway-value/quick-seed0/metrics.json"))
    assert not freeway.at_most  # every Freeway episode runs its full 2,048 steps


def test_the_summary_adds_what_a_run_builds_on():
    runs = {(r.experiment, r.variant, r.seed): r for r in read_runs(RESULTS) if r.profile == "quick"}
    wm, coupling = runs[("boxing-wm", "separable-64", 3)], runs[("boxing-wm-alphazero", "own-memory", 3)]
    own = alphazero_steps(read("boxing-wm-alphazero/quick-seed3/own-memory/metrics.json"))
    assert coupling.agent_steps == wm.agent_steps + own.total and coupling.steps_at_most
    agent = runs[("planet-boxing-agent", None, 0)]
    value = runs[("planet-boxing-value", "lean-value-rewards-0.7", 0)]
    assert agent.agent_steps == read("planet-boxing-agent/quick-seed0/metrics.json")["env_steps"]
    assert value.agent_steps == agent.agent_steps + value_steps(
        read("planet-boxing-value/quick-seed0/lean-value-rewards-0.7/metrics.json")).total
    search = runs[("sokoban-search", None, 0)]
    report = runs[("sokoban-search", "boxoban-medium, 1000 report levels", 0)]
    assert report.agent_steps == search.agent_steps == store_steps(read("sokoban-search/quick-seed0/metrics.json")).total
    other = runs[("sokoban-search", "boxoban-unfiltered, 1000 report levels", 1)]  # a report alone: the steps it states
    assert other.agent_steps == read("sokoban-search/quick-seed1/boxoban-report-1000.json")["env_steps"]


def test_the_front_doors_column_states_ours_and_the_published_budget():
    row = {"agent_steps": [4_591_378, 4_700_001, None], "steps_at_most": False}
    assert agent_steps(row, best_atari_100k("boxing")) == "4.6M-4.7M (2 of 3 seeds) (100k)"
    assert agent_steps({"agent_steps": [98_230], "steps_at_most": True}, BOXOBAN["unfiltered"]) == "at most 98k (2e9)"
    assert agent_steps({"agent_steps": [None]}) == "" and agent_steps(None) == ""
    assert all(ref.budget == "100k" for refs in ATARI_100K.values() for ref in refs)
    assert short(999) == "999" and short(35_720) == "36k" and Steps({"a": 1}) + Steps({"b": 2}, True) == Steps(
        {"a": 1, "b": 2}, True)
    assert (Steps({"store": 5}) + Steps({"store": 7})).total == 12  # a stage named twice loses no steps


def test_every_headline_row_states_its_budget():
    from wmthesis.headline import HEADLINES, headline_rows

    for entry in headline_rows(summarise(read_runs(RESULTS))):
        assert agent_steps(entry["row"], entry["headline"].published), entry["headline"].title
