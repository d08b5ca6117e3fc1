"""World Models that learn inside their dream (wmthesis.world_models.dream): the budget of real
steps is never exceeded and every stage's steps are recorded; the dream starts from real states."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from wmthesis.world_models.dream import Budget, BudgetExceeded, play_bouts


def test_a_budget_refuses_what_it_has_not_left():
    budget = Budget(1000)
    budget.charge("random play", 600)
    budget.charge("controller's bouts", 300)
    assert (budget.used, budget.remaining, budget.spent) == (900, 100, {"random play": 600, "controller's bouts": 300})
    with pytest.raises(BudgetExceeded, match="controller's bouts spent 101 real agent steps; 100 of 1,000 were left"):
        budget.charge("controller's bouts", 101)
    assert budget.used == 900  # a refused charge spends nothing
    with pytest.raises(ValueError, match="must be positive"):
        Budget(0)


def test_real_bouts_are_capped_to_what_the_budget_has_left_and_join_the_store(tmp_path):
    from wmthesis.data import EpisodeStore
    from wmthesis.rollouts import collect
    from wmthesis.world_models.controller import num_parameters
    from wmthesis.world_models.memory import Memory

    store = collect("boxing", 1, tmp_path / "real.h5", seed=0, preprocessing="world_models", max_steps=5,
                    progress=False)
    memory = Memory(4, 18, hidden_size=8)
    vision = lambda frames: torch.zeros(len(frames), 4)  # noqa: E731
    budget = Budget(155)
    budget.charge("random play", 5)
    params = np.random.default_rng(0).normal(size=num_parameters(4 + 8, 18))
    returns, steps = play_bouts(params, vision, memory, [3, 4], budget, "controller's bouts", store, noop_max=3)
    assert steps == [75, 75] and len(returns) == 2  # 150 left, two bouts: 75 steps each at most
    assert budget.spent == {"random play": 5, "controller's bouts": 150} and budget.remaining == 0
    with EpisodeStore(store) as episodes:
        assert len(episodes) == 3 and list(episodes.episode_lengths) == [5, 75, 75]
        assert not episodes.episode(1)["terminals"].any()  # cut by the budget, not ended by the game
    assert play_bouts(params, vision, memory, [5], budget, "controller's bouts", store, noop_max=3) == ([], [])


def test_a_dream_from_a_real_state_continues_the_memory_where_the_real_steps_left_it():
    from wmthesis.world_models.controller import num_parameters
    from wmthesis.world_models.evolution import dream_population
    from wmthesis.world_models.memory import Memory

    torch.manual_seed(0)
    memory = Memory(4, 18, kind="deterministic", hidden_size=8).eval()
    z, actions = torch.randn(1, 6, 4), torch.randint(18, (1, 6))
    with torch.no_grad():
        out = memory(z, actions)  # six real steps
        warmed = memory(z[:, :5], actions[:, :5])  # five, then the dream from the sixth's latent
    params = np.zeros((1, num_parameters(4 + 8, 18)))
    params[0, -18:] = -10.0  # the bias: every action but the one taken scores lower
    params[0, -18 + int(actions[0, 5])] = 10.0
    returns, _ = dream_population(params, memory, z[:, 5], start_state=warmed.state, max_steps=1)
    assert returns[0, 0] == pytest.approx(float(out.reward[0, 5]), abs=1e-6)
    fresh, _ = dream_population(params, memory, z[:, 5], max_steps=1)
    assert fresh[0, 0] != pytest.approx(returns[0, 0])  # from an episode's start: another state


def test_a_smoke_run_spends_at_most_its_budget_records_each_stage_and_ships_an_agent(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    import wmthesis
    from wmthesis.budget import dream_steps
    from wmthesis.experiments import reproduce
    from wmthesis.summary import run_scores

    metrics = reproduce("boxing-wm-dream", "smoke", 0, progress=False)
    budget = metrics["budget"]
    assert sum(budget["spent"].values()) <= budget["total"] == 400
    assert set(budget["spent"]) == {"random play", "controller's bouts"}
    assert dream_steps(metrics).total == sum(budget["spent"].values())
    steps = [i["real_steps"] for i in metrics["iterations"]]
    assert steps == sorted(steps) and steps[-1] == sum(budget["spent"].values())
    for record in metrics["iterations"]:  # each iteration's controller in its dream and in the real game
        assert {"dream_return", "real_return", "real_per_dream", "real_returns"} <= set(record)
    assert metrics["kept_iteration"] in [i["iteration"] for i in metrics["iterations"]]
    assert run_scores(metrics) == {"short-dreams": metrics["score"]["mean"]}
    agent = wmthesis.load("boxing-wm-dream", profile="smoke")
    assert agent.play(bouts=2) == metrics["returns"]  # the bouts of its score
