"""CEM with a learned terminal value: without a value it is the thesis's CEM, the same draws
included; with H = 1 it is the value agent; in between, the return by hand."""
import dataclasses

import numpy as np
import pytest
import torch

from wmthesis.planet.rssm import RSSM
from wmthesis.planet.agent import PlanetMind
from wmthesis.value.latent_value import LatentValue, after_action
from wmthesis.value.planner import ValuePlanetMind, value_returns

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py
SIZES = dict(horizon=4, candidates=64, top_k=8, iterations=3)


def model_and_value(actions: int = 5):
    torch.manual_seed(0)
    model = RSSM(actions, belief_size=16, state_size=4, hidden_size=16, reward_hidden_size=8).eval()
    return model, LatentValue(20, 16, heads=2).eval()


def frames(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (64, 64, 3), dtype=np.uint8) for _ in range(n)]


def test_without_a_value_it_is_the_thesis_cem_draw_for_draw():
    model, _ = model_and_value()
    thesis = PlanetMind(model, **SIZES, generator=torch.Generator().manual_seed(3))
    ours = ValuePlanetMind(model, None, **SIZES, generator=torch.Generator().manual_seed(3))
    for frame in frames(4):
        assert np.array_equal(thesis.plan(frame), ours.plan(frame))
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    actions = torch.nn.functional.one_hot(torch.randint(5, (32, 6)), 5).float()
    with torch.no_grad():
        expected = model.imagined_returns(belief, state, actions, torch.Generator().manual_seed(1))
        assert torch.equal(value_returns(model, None, belief, state, actions, torch.Generator().manual_seed(1)), expected)


def test_with_one_step_it_is_the_value_agent():
    model, value = model_and_value()
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    with torch.no_grad():
        q = value(after_action(model, belief.expand(5, -1), state.expand(5, -1), torch.arange(5)))
        assert torch.allclose(value_returns(model, value, belief, state, torch.eye(5)[:, None]), q)
    # the planner's choice with every action among its candidates is the argmax of Q
    mind = ValuePlanetMind(model, value, horizon=1, candidates=300, top_k=1, iterations=1,
                           generator=torch.Generator().manual_seed(0))
    for frame in frames(5):
        choice = int(np.argmax(mind.plan(frame)))
        with torch.no_grad():
            q = value(after_action(model, mind.belief.expand(5, -1), mind.state.expand(5, -1), torch.arange(5)))
        assert choice == int(q.argmax())


def test_the_return_by_hand_imagined_rewards_then_the_discounted_value():
    model, value = model_and_value()
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    actions = torch.nn.functional.one_hot(torch.tensor([[2, 0, 4]]), 5).float()
    with torch.no_grad():
        generator = torch.Generator().manual_seed(5)
        h1, p1 = model.transition(belief, state, actions[:, 0])
        s1 = p1.sample(generator)
        h2, p2 = model.transition(h1, s1, actions[:, 1])
        s2 = p2.sample(generator)
        h3, p3 = model.transition(h2, s2, actions[:, 2])
        by_hand = model.reward(h1, s1) + 0.9 * model.reward(h2, s2) + 0.81 * value(torch.cat([h3, p3.mean], -1))
        ours = value_returns(model, value, belief, state, actions, torch.Generator().manual_seed(5), discount=0.9)
    assert torch.allclose(ours, by_hand)
    with pytest.raises(ValueError, match="discount"):
        ValuePlanetMind(model, value, discount=0.0, **SIZES)


def test_plan_choices_follow_one_belief_and_one_step_with_the_value_is_the_value_agent():
    from wmthesis.planet.config import PlaNetConfig
    from wmthesis.value.config import ValuePlannerConfig
    from wmthesis.value.latent_value import ValueMind
    from wmthesis.value.planner import PLANNERS, plan_choices

    model, value = model_and_value()
    planet = PlaNetConfig(horizon=3, candidates=200, top_k=20, iterations=3)
    shown, taken = np.stack(frames(6)), np.array([1, 4, 0, 2, 3, 1])
    choices = plan_choices(model, value, planet, ValuePlannerConfig(horizon=1), shown, taken, seed=2)
    assert set(choices) == set(PLANNERS) and all(len(c) == 6 for c in choices.values())
    # the value alone is the value agent along the same frames and actions
    mind = ValueMind(model, value, planet.bits)
    for t, frame in enumerate(shown):
        assert choices["value alone"][t] == int(np.argmax(mind.plan(frame)))
        mind.prev_action = torch.nn.functional.one_hot(torch.tensor([int(taken[t])]), 5).float()
    # CEM over one step with the value at its end finds the value's argmax among 5 actions
    assert np.array_equal(choices["CEM with value"], choices["value alone"])
    # and the thesis's CEM, blind to the value, does not always agree with it
    assert not np.array_equal(choices["CEM (thesis)"], choices["value alone"])


def test_the_planners_over_seeds_each_seed_then_the_mean_and_its_t_interval():
    from wmthesis.value.tables import planner_rows

    def metrics(x):
        return {"random": {"mean": 0.0}, "planet": {"mean": x - 5}, "value": {"mean": x + 1},
                "value_planner": {"full": {"mean": x}, "first": {"mean": x / 2}}}

    rows = {row[0]: row[1:] for row in planner_rows({0: metrics(10.0), 3: metrics(20.0)})}
    # mean 15, s = sqrt(50), t(0.975, 1) = 12.706: 15 -+ 12.706 * sqrt(50) / sqrt(2) = 15 -+ 63.5
    assert rows["CEM with the value, full bouts"] == ["10.0", "20.0", "15.0 [-48.5, 78.5]"]
    assert rows["CEM with the value, first 500 steps"][:2] == ["5.0", "10.0"]
    assert planner_rows({0: metrics(7.0)})[3] == ["CEM with the value, full bouts", "7.0", "7.0"]  # one seed: no interval
    # another variant's CEM beside, seed for seed (by seed, not by order)
    rows = planner_rows({0: metrics(10.0), 3: metrics(20.0)}, beside={"default": {3: metrics(4.0), 0: metrics(2.0)}})
    assert rows[-2] == ["CEM with the value (default), full bouts", "2.0", "4.0", "3.0 [-9.7, 15.7]"]
    assert rows[-1][:3] == ["CEM with the value (default), first 500 steps", "1.0", "2.0"]
    with pytest.raises(ValueError, match="seeds"):
        planner_rows({0: metrics(1.0)}, beside={"default": {1: metrics(1.0)}})


def test_imagining_the_priors_mean_is_one_path_by_hand_and_draws_nothing():
    model, value = model_and_value()
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    actions = torch.nn.functional.one_hot(torch.tensor([[1, 3, 0], [4, 4, 2]]), 5).float()
    with torch.no_grad():
        h1, p1 = model.transition(belief.expand(2, -1), state.expand(2, -1), actions[:, 0])
        h2, p2 = model.transition(h1, p1.mean, actions[:, 1])
        h3, p3 = model.transition(h2, p2.mean, actions[:, 2])
        by_hand = model.reward(h1, p1.mean) + 0.5 * model.reward(h2, p2.mean) + 0.25 * value(torch.cat([h3, p3.mean], -1))
        generator = torch.Generator().manual_seed(9)
        before = generator.get_state()
        ours = value_returns(model, value, belief, state, actions, generator, discount=0.5, imagine="mean")
        assert torch.equal(generator.get_state(), before)  # no sampling noise in the return
        sampled = value_returns(model, value, belief, state, actions, torch.Generator().manual_seed(9), discount=0.5)
    assert torch.allclose(ours, by_hand) and not torch.allclose(sampled, by_hand)
    with pytest.raises(ValueError, match="imagine"):
        ValuePlanetMind(model, value, imagine="median", **SIZES)


TWO_PLANS = torch.nn.functional.one_hot(torch.tensor([[2, 0, 4], [1, 1, 3]]), 5).float()  # (J=2, H=3, A=5)


def imagined_features(model, belief, state, actions, seed: int) -> list[torch.Tensor]:
    """By hand: the value's features (J, H + S) after each step of ``actions`` (J, H, A), each next
    state sampled from the prior as ``value_returns`` samples it (one generator, in order)."""
    generator, features = torch.Generator().manual_seed(seed), []
    belief, state = belief.expand(len(actions), -1), state.expand(len(actions), -1)
    for t in range(actions.shape[1]):
        belief, prior = model.transition(belief, state, actions[:, t])
        features.append(torch.cat([belief, prior.mean], -1))
        state = prior.sample(generator)
    return features


def test_the_values_rewards_score_every_imagined_step_by_hand_and_one_step_is_the_value_agent():
    model, value = model_and_value()
    belief, state, actions = torch.randn(1, 16), torch.randn(1, 4), TWO_PLANS
    with torch.no_grad():
        q = [value(features) for features in imagined_features(model, belief, state, actions, seed=5)]
        by_hand = q[0] + 0.9 * q[1] + 0.81 * q[2]  # no reward head anywhere
        ours = value_returns(model, value, belief, state, actions, torch.Generator().manual_seed(5), discount=0.9,
                             rewards="value")
        assert torch.allclose(ours, by_hand)
        heads = value_returns(model, value, belief, state, actions, torch.Generator().manual_seed(5), discount=0.9)
        assert not torch.allclose(heads, by_hand)  # the thesis's reward head in between
        one = value_returns(model, value, belief, state, torch.eye(5)[:, None], rewards="value")
        assert torch.allclose(one, value(after_action(model, belief.expand(5, -1), state.expand(5, -1), torch.arange(5))))
    with pytest.raises(ValueError, match="rewards must be one of"):
        ValuePlanetMind(model, None, rewards="value", **SIZES)
    with pytest.raises(ValueError, match="rewards must be one of"):
        ValuePlanetMind(model, value, rewards="critic", **SIZES)


def test_pessimism_scores_imagined_steps_by_the_heads_mean_less_their_spread_and_leaves_the_first_step():
    from wmthesis.value.planner import pessimistic_q

    model, value = model_and_value()
    belief, state, actions = torch.randn(1, 16), torch.randn(1, 4), TWO_PLANS
    with torch.no_grad():
        heads = [value.each(features) for features in imagined_features(model, belief, state, actions, seed=5)]
        mean, spread = [q.mean(-1) for q in heads], [q.std(-1) for q in heads]
        by_hand = mean[0] + 0.9 * (mean[1] - 2.0 * spread[1]) + 0.81 * (mean[2] - 2.0 * spread[2])
        ours = value_returns(model, value, belief, state, actions, torch.Generator().manual_seed(5), discount=0.9,
                             rewards="value", pessimism=2.0)
        assert torch.allclose(ours, by_hand) and (spread[1] > 0).all()
        plain = value_returns(model, value, belief, state, actions, torch.Generator().manual_seed(5), discount=0.9,
                              rewards="value")
        assert (ours < plain).all()  # the penalty only lowers
        one = torch.eye(5)[:, None]  # one step: the value agent's own Q, whatever the pessimism
        assert torch.equal(value_returns(model, value, belief, state, one, rewards="value", pessimism=5.0),
                           value_returns(model, value, belief, state, one, rewards="value"))
        features = torch.randn(7, 20)
        assert torch.equal(pessimistic_q(value, features, 0.0), value(features))
    with pytest.raises(ValueError, match="pessimism"):
        ValuePlanetMind(model, value, pessimism=-1.0, **SIZES)
    with pytest.raises(ValueError, match="pessimism"):
        ValuePlanetMind(model, None, pessimism=1.0, **SIZES)
    with pytest.raises(ValueError, match="2 heads"):
        pessimistic_q(LatentValue(20, 16, heads=1), torch.randn(3, 20), 1.0)


def test_shared_imagined_states_give_candidates_of_the_same_actions_the_same_return():
    from wmthesis.value.planner import imagined_state

    model, value = model_and_value()
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    same = torch.nn.functional.one_hot(torch.tensor([[2, 0, 4]] * 6 + [[1, 3, 3]] * 2), 5).float()
    with torch.no_grad():
        shared = value_returns(model, value, belief, state, same, torch.Generator().manual_seed(2), imagine="shared",
                               rewards="value")
        sampled = value_returns(model, value, belief, state, same, torch.Generator().manual_seed(2), rewards="value")
        assert torch.allclose(shared[:6], shared[0].expand(6)) and shared[6] == shared[7] and shared[0] != shared[6]
        assert sampled[:6].std() > 1e-4  # the thesis's draws: the same actions, another return each
        _, prior = model.transition(belief.expand(3, -1), state.expand(3, -1), torch.eye(5)[:3])
        eps = torch.randn(1, 4, generator=torch.Generator().manual_seed(7))
        assert torch.allclose(imagined_state(prior, torch.Generator().manual_seed(7), "shared"), prior.mean + prior.std * eps)
        assert torch.equal(imagined_state(prior, None, "mean"), prior.mean)
    with pytest.raises(ValueError, match="imagine"):
        ValuePlanetMind(model, value, imagine="median", **SIZES)


def test_particles_average_each_candidates_paths_and_shrink_the_noise_of_its_return():
    model, value = model_and_value()
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    same = torch.nn.functional.one_hot(torch.tensor([[2, 0, 4]] * 200), 5).float()
    with torch.no_grad():
        paths = value_returns(model, value, belief, state, same[:3].repeat_interleave(8, 0),
                              torch.Generator().manual_seed(4), discount=0.7, rewards="value")
        ours = value_returns(model, value, belief, state, same[:3], torch.Generator().manual_seed(4), discount=0.7,
                             rewards="value", particles=8)
        assert torch.allclose(ours, paths.view(3, 8).mean(1))  # the same draws, each candidate its 8 paths' mean
        one = value_returns(model, value, belief, state, same, torch.Generator().manual_seed(1), rewards="value")
        many = value_returns(model, value, belief, state, same, torch.Generator().manual_seed(1), rewards="value",
                             particles=16)
        assert 2.5 < one.std() / many.std() < 6.5  # sqrt(16) = 4: noise shrinks as the paths' mean
        assert abs(one.mean() - many.mean()) < 3 * one.std() / 200 ** 0.5 + 3 * many.std() / 200 ** 0.5
        shared = value_returns(model, value, belief, state, same[:4], torch.Generator().manual_seed(3),
                               rewards="value", imagine="shared", particles=5)
        assert torch.allclose(shared, shared[0].expand(4))  # 5 draws shared: equal actions, equal returns
        one = torch.eye(5)[:, None]  # one step draws nothing: the value agent's Q, whatever K
        assert torch.allclose(value_returns(model, value, belief, state, one, particles=4), value_returns(model, value, belief, state, one))
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match="particles"):
            ValuePlanetMind(model, value, particles=bad, **SIZES)


def test_the_value_seeds_cems_first_step_with_the_z_scores_of_q():
    from wmthesis.planet.cem import cem_belief
    from wmthesis.value.planner import value_scores

    model, value = model_and_value()
    belief, state = torch.randn(1, 16), torch.randn(1, 4)
    with torch.no_grad():
        q = value(after_action(model, belief.expand(5, -1), state.expand(5, -1), torch.arange(5)))
        mean = value_scores(model, value, belief, state, scale=2.0, horizon=3)
    z = (q - q.mean()) / q.std()
    assert mean.shape == (3, 5) and torch.allclose(mean[0], 2.0 * z) and not mean[1:].any()
    # a strong seed holds CEM's first step where it points when every return ties ...
    strong = torch.zeros(3, 5)
    strong[0, 3] = 50.0
    flat = cem_belief(lambda a: torch.zeros(len(a)), 5, 3, 64, 8, 3, torch.Generator().manual_seed(0), mean=strong)
    assert int(flat.mean[0].argmax()) == 3
    # ... and the returns still overrule it when they disagree
    best_first_0 = cem_belief(lambda a: a[:, 0, 0] * 10.0, 5, 3, 200, 20, 4, torch.Generator().manual_seed(0),
                              mean=strong * 0.05)
    assert int(best_first_0.mean[0].argmax()) == 0
    # no seed is the thesis's zero mean, draw for draw
    plain = cem_belief(lambda a: a[:, 0, 1], 5, 3, 64, 8, 3, torch.Generator().manual_seed(4))
    zeros = cem_belief(lambda a: a[:, 0, 1], 5, 3, 64, 8, 3, torch.Generator().manual_seed(4), mean=torch.zeros(3, 5))
    assert torch.equal(plain.mean, zeros.mean)
    with pytest.raises(ValueError, match="first mean"):
        cem_belief(lambda a: torch.zeros(len(a)), 5, 3, 64, 8, 3, mean=torch.zeros(2, 5))
    with pytest.raises(ValueError, match="value_prior"):
        ValuePlanetMind(model, None, value_prior=1.0, **SIZES)


def test_a_seeded_planner_over_one_step_is_still_the_value_agent():
    model, value = model_and_value()
    mind = ValuePlanetMind(model, value, horizon=1, candidates=300, top_k=1, iterations=1, value_prior=1.0,
                           imagine="mean", generator=torch.Generator().manual_seed(0))
    for frame in frames(4):
        choice = int(np.argmax(mind.plan(frame)))
        with torch.no_grad():
            q = value(after_action(model, mind.belief.expand(5, -1), mind.state.expand(5, -1), torch.arange(5)))
        assert choice == int(q.argmax())


def test_a_planner_cache_from_before_a_field_was_added_reads_as_what_it_did(tmp_path):
    import json

    from wmthesis.value.config import ValuePlannerConfig
    from wmthesis.value.bouts import cached_plan

    path = tmp_path / "value_planner.json"
    path.write_text(json.dumps({"key": {"round": 2, "planner": {"horizon": 3, "discount": 1.0}}, "scores": {"x": 1}}))
    # written before imagine and value_prior existed: it imagined samples (imagine's default) from
    # CEM's zero mean (value_prior 0, no longer the default)
    did = {"round": 2, "planner": dataclasses.asdict(ValuePlannerConfig(horizon=3, value_prior=0.0))}
    assert cached_plan(path, did)["scores"] == {"x": 1}
    assert cached_plan(path, {**did, "planner": dataclasses.asdict(ValuePlannerConfig(horizon=3))}) is None  # seeded
    assert cached_plan(path, {**did, "planner": dataclasses.asdict(ValuePlannerConfig(horizon=3, imagine="mean",
                                                                                       value_prior=0.0))}) is None
    assert cached_plan(path, {**did, "round": 3}) is None


def test_planner_bouts_are_saved_as_they_end_and_a_cut_off_run_plays_only_the_rest(tmp_path):
    import json

    from wmthesis.value.config import ValuePlannerConfig
    from wmthesis.runs import played_bouts

    path = tmp_path / "scores-bouts.json"
    key = {"round": 1, "planner": dataclasses.asdict(ValuePlannerConfig())}
    calls = [(dict, [("return", float(i))]) for i in range(4)]  # bout i returns i
    path.write_text(json.dumps({"key": key, "plays": {"2": {"return": -7.0}}}))  # bout 2 ended before the cut
    plays = played_bouts(path, key, False, calls)
    assert [p["return"] for p in plays] == [0.0, 1.0, -7.0, 3.0]  # bout 2 was not played again
    assert {int(i) for i in json.loads(path.read_text())["plays"]} == {0, 1, 2, 3}
    other = {**key, "round": 2}  # saved for another round: played again
    assert [p["return"] for p in played_bouts(path, other, False, calls)] == [0.0, 1.0, 2.0, 3.0]


def test_a_planner_variant_copies_a_run_fitted_with_its_own_value_config():
    from wmthesis.value.variants import VALUE_VARIANTS

    planners = [name for name, v in VALUE_VARIANTS.items() if set(v.changes) == {"planner"}]
    assert planners == ["lean-value-rewards-0.7", "own-rewards"]
    for variant in planners:  # its value is copied (start_from), not fitted: the copy must be the value it names
        copied = VALUE_VARIANTS[variant].builds_on
        assert copied != variant and VALUE_VARIANTS.changes(variant, "value") == VALUE_VARIANTS.changes(copied, "value")
        assert "value" in VALUE_VARIANTS[copied].changes  # a planner-only run holds no value of its own to copy
    assert VALUE_VARIANTS.folder_name("scored-rounds") is None and VALUE_VARIANTS.folder_name(None) == "lean-value-rewards-0.7"


def test_groups_of_bouts_play_in_one_pool_each_saved_in_its_own_file(tmp_path):
    import json

    from wmthesis.runs import played_groups

    paths = [tmp_path / "a.json", tmp_path / "b.json"]
    keys = [{"lever": "a"}, {"lever": "b"}]
    calls = [[(dict, [("return", float(10 * g + i))]) for i in range(3)] for g in range(2)]
    paths[1].write_text(json.dumps({"key": keys[1], "plays": {"0": {"return": -1.0}}}))  # ended before a cut
    plays = played_groups([(paths[g], keys[g], calls[g], None) for g in range(2)], False)
    assert [[p["return"] for p in group] for group in plays] == [[0.0, 1.0, 2.0], [-1.0, 11.0, 12.0]]
    for g in range(2):  # each group's bouts in its own file, under its own key
        saved = json.loads(paths[g].read_text())
        assert saved["key"] == keys[g] and sorted(saved["plays"]) == ["0", "1", "2"]


def test_the_planner_levers_table_is_paired_against_the_first_lever():
    from wmthesis.value.config import ValuePlannerConfig
    from wmthesis.value.variants import BOXING_PLANNER_LEVERS as PLANNER_LEVERS
    from wmthesis.value.tables import planner_lever_rows
    from wmthesis.metrics import score_summary

    def scores(returns, first):
        return {"returns": returns, "full": score_summary(returns), "first": score_summary(first)}

    rows = planner_lever_rows({"value seeds CEM": scores([2.0, 4.0, 0.0], [1.0, 1.0, 1.0]),
                               "the value's rewards, discount 0.7": scores([5.0, 5.0, 5.0], [2.0, 3.0, 4.0])},
                              PLANNER_LEVERS)
    assert rows[0] == ["value seeds CEM", "(the default)", "2.0 ± 1.6", "1.0", "+0.0 ± 0.0"]
    # differences 3, 1, 5: mean 3, standard error 2 / sqrt(3)
    assert rows[1] == ["the value's rewards, discount 0.7", "rewards=value, discount=0.7", "5.0 ± 0.0", "3.0", "+3.0 ± 1.2"]
    # the levers are stated against the default planner: the first is the thesis's CEM start
    default = ValuePlannerConfig()
    assert default.rewards != "value" and dataclasses.replace(default, **PLANNER_LEVERS["the value's rewards, discount 0.7"]).rewards == "value"


def test_the_agent_rules_table_names_each_rules_rounds_and_pairs_them():
    from wmthesis.value.tables import agent_rows
    from wmthesis.metrics import score_summary

    def scores(rounds, returns):
        return {"rounds": rounds, "returns": returns, "full": score_summary(returns), "first": score_summary(returns)}

    rows = agent_rows({"round chosen on validation": scores([6], [0.0, 10.0]),
                       "mean of the last 3": scores([8, 9, 10], [4.0, 12.0])})
    assert rows[0][:2] == ["round chosen on validation", "round 6"] and rows[0][-1] == "+0.0 ± 0.0"
    assert rows[1] == ["mean of the last 3", "rounds 8-10", "8.0 ± 4.0", "8.0", "+3.0 ± 1.0"]


def test_the_reward_head_refit_on_a_run_s_own_bouts_learns_them_once_and_is_what_the_planner_plans_with(tmp_path, monkeypatch):
    import gymnasium as gym
    from wmthesis.data import EpisodeStore
    from wmthesis.value import own_rewards
    from wmthesis.value.config import LatentValueConfig, ValuePlannerConfig
    from wmthesis.rollouts import play_random_episode

    class PunchNow(gym.Env):  # action 1 of 3 pays at once: the features after it tell it apart
        observation_space = gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
        action_space = gym.spaces.Discrete(3)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.t = 0
            return np.zeros((64, 64, 3), np.uint8), {}

        def step(self, action):
            self.t += 1
            return np.zeros((64, 64, 3), np.uint8), float(action == 1), False, self.t >= 24, {}

    torch.manual_seed(0)
    model = RSSM(3, belief_size=16, state_size=4, hidden_size=16, reward_hidden_size=8).eval()
    env = PunchNow()
    with EpisodeStore(tmp_path / "episodes.h5", "a", preprocessing="planet", seed=0, obs_shape=(64, 64, 3)) as store:
        for index in range(6):
            store.append_episode(**play_random_episode(env, 0, index))
    config = LatentValueConfig(fit_updates=300, batch_size=64, lr=1e-2)
    before = {k: v.clone() for k, v in model.reward_net.state_dict().items()}
    record = own_rewards.own_reward_head(model, tmp_path, 5, config, seed=0)
    assert record["bouts"] == 6 and record["fit"]["steps"] == 6 * 24
    assert record["fit"]["after"] < 0.2 * record["fit"]["before"]  # it learnt which action pays
    assert all(torch.equal(before[k], v) for k, v in model.reward_net.state_dict().items())  # the model untouched
    # kept: asked again for the same bouts, nothing is refit; a bout more, it is
    monkeypatch.setattr(own_rewards, "reward_dataset", lambda *a: pytest.fail("refit for the same bouts"))
    assert own_rewards.own_reward_head(model, tmp_path, 5, config, seed=0)["fit"] == record["fit"]
    monkeypatch.undo()
    with EpisodeStore(tmp_path / "episodes.h5", "a", preprocessing="planet", seed=0, obs_shape=(64, 64, 3)) as store:
        store.append_episode(**play_random_episode(env, 0, 6))
    assert own_rewards.own_reward_head(model, tmp_path, 5, config, seed=0)["bouts"] == 7
    # the planner's imagined rewards are the refit head's: action 1 now scores above the others
    own_rewards.with_own_rewards(model, tmp_path)
    belief, state = torch.zeros(1, 16), torch.zeros(1, 4)
    with torch.no_grad():
        rewards = value_returns(model, None, belief, state, torch.eye(3)[:, None], imagine="mean")
    assert int(rewards.argmax()) == 1 and float(rewards[1] - rewards[[0, 2]].max()) > 0.5
    other = RSSM(3, belief_size=16, state_size=4, hidden_size=16, reward_hidden_size=8).eval()  # another model's weights
    assert own_rewards.own_reward_head(other, tmp_path, 5, config, seed=0)["model"] != record["model"]  # refit for it
    # bad input: a run with no refit head; an unknown head; the own head with the value's rewards
    with pytest.raises(FileNotFoundError, match="own-rewards.pt"):
        own_rewards.with_own_rewards(model, tmp_path / "elsewhere")
    (tmp_path / "corrupt").mkdir()
    (tmp_path / "corrupt" / own_rewards.OWN_REWARDS).write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="corrupt/own-rewards.pt: not a refit reward head"):
        own_rewards.with_own_rewards(model, tmp_path / "corrupt")
    with pytest.raises(ValueError, match="reward_head must be one of"):
        own_rewards.check_reward_head(ValuePlannerConfig(reward_head="mine"))
    with pytest.raises(ValueError, match="rewards must be 'model'"):
        own_rewards.check_reward_head(ValuePlannerConfig(reward_head="own", rewards="value"))
