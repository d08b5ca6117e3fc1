"""Controller (thesis 4.2.2) and its CMA-ES training: batched evaluation, learning, resume, dream."""
import json
import pickle

import numpy as np
import pytest
import torch

from wmthesis.config import for_profile
from wmthesis.core import loop
from wmthesis.envs import make_env
from wmthesis.envs.vector import make_game
from wmthesis.training import ConfigMismatch
from wmthesis.world_models.config import ControllerConfig
from wmthesis.world_models.controller import Controller, ControllerMind, population_scores, unflatten
from wmthesis.world_models.evolution import (dream_population, episode_seeds, evaluate_population, load_run,
                                             new_strategy, train_controller)
from wmthesis.world_models.figures import plot_learning_curve
from wmthesis.world_models.memory import Memory


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py


def pooled(frames: torch.Tensor) -> torch.Tensor:
    """A cheap vision for tests: (N, 64, 64, 3) uint8 -> mean grey of 4 x 4 blocks (N, 16)."""
    grey = frames.float().mean(-1) / 255
    return grey.reshape(len(frames), 4, 16, 4, 16).mean((2, 4)).flatten(1)


def grid(observations: torch.Tensor) -> torch.Tensor:
    """Sokoban grid observations (N, 25) codes -> (N, 25) floats."""
    return observations.float() / 6


def tiny_memory(latent_size: int, n_actions: int, seed: int = 0) -> Memory:
    torch.manual_seed(seed)
    return Memory(latent_size, n_actions, hidden_size=8, n_gaussians=2).eval()


def random_params(P: int, memory: Memory, seed: int = 0) -> np.ndarray:
    D = memory.n_actions * (memory.latent_size + memory.hidden_size + 1)
    return np.random.default_rng(seed).normal(0, 1, (P, D))


def test_flat_parameters_round_trip_and_population_scores_match_the_module():
    torch.manual_seed(0)
    params = torch.randn(3, Controller(4, 5, 6).num_parameters)
    z, h = torch.randn(3, 2, 4), torch.randn(3, 2, 5)
    weight, bias = unflatten(params, 9, 6)
    scores = population_scores(weight, bias, torch.cat([z, h], -1))
    for p in range(3):
        controller = Controller.from_flat(params[p].numpy(), 4, 5, 6)
        assert np.allclose(controller.get_flat(), params[p].numpy(), atol=1e-7)
        assert torch.allclose(controller(z[p], h[p]), scores[p], atol=1e-5)
    with pytest.raises(ValueError, match="expected 60 parameters"):
        Controller(4, 5, 6).set_flat(np.zeros(59))


def test_vector_game_plays_like_the_gymnasium_env():
    """ale-py's vector env with our crop/resize gives make_env's World Models frames and rewards."""
    actions = np.random.default_rng(0).integers(0, 18, 80)
    env = make_env("boxing", preprocessing="world_models")
    game = make_game("boxing", 2, noop_max=0)
    frame, _ = env.reset(seed=0)
    frames = game.reset(np.array([0, 1]))
    for action in actions:
        assert np.array_equal(frames[0], frame) and np.array_equal(frames[1], frame)
        frame, reward, *_ = env.step(action)
        frames, rewards, _ = game.step(np.array([action, action]))
        assert rewards[0] == rewards[1] == reward
    game.close()


def test_no_ops_vary_the_starts_and_are_seeded():
    memory = tiny_memory(16, 18)
    params = random_params(1, memory)
    game = make_game("boxing", 4, noop_max=30)
    seeds = episode_seeds(0, 0, 4)
    evaluate_population(params, game, pooled, memory, seeds=seeds, max_steps=20)
    noops, frames = game.noops.copy(), game.frames.copy()
    evaluate_population(params, game, pooled, memory, seeds=seeds, max_steps=20)
    assert np.array_equal(game.noops, noops) and np.array_equal(game.frames, frames)
    game.close()
    assert len(set(noops)) > 1 and np.all((0 <= noops) & (noops < 30))
    assert len({frame.tobytes() for frame in frames}) > 1  # one greedy controller, different episodes


def test_batched_evaluation_matches_the_mind_in_loop():
    """Candidate p of a batched evaluation scores what ControllerMind scores in HumbleRL's loop."""
    memory = tiny_memory(16, 3)
    params = random_params(3, memory, seed=1)
    game = make_game("freeway", 3, noop_max=0)
    returns, steps = evaluate_population(params, game, pooled, memory, seeds=np.zeros(1, np.int64), max_steps=120)
    game.close()
    env = make_env("freeway", preprocessing="world_models")
    for p in range(3):
        mind = ControllerMind(pooled, memory, Controller.from_flat(params[p], 16, 8, 3))
        history = loop(env, mind, callbacks=[mind], max_steps=120)
        assert history[0]["return"] == returns[p, 0] and history[0]["steps"] == steps[p, 0]
    with pytest.raises(RuntimeError, match="callbacks=\\[mind\\]"):
        loop(env, mind, max_steps=3)


@pytest.mark.parametrize("diagonal", [False, True])
def test_cma_es_beats_random_play_within_a_few_generations(diagonal):
    """Freeway, 200 steps: random play scores 0; the evolved controller crosses the road."""
    cfg = for_profile(ControllerConfig, "smoke", generations=2, episodes=1, max_steps=200, eval_every=2,
                      eval_episodes=4, diagonal=diagonal)
    run = train_controller("freeway", pooled, tiny_memory(16, 3), cfg, progress=False)
    game = make_game("freeway", 4)
    game.reset(episode_seeds(cfg.seed, 0, 4, stream=1))
    rng, random_returns = np.random.default_rng(0), np.zeros(4)
    for _ in range(200):
        random_returns += game.step(rng.integers(0, 3, 4))[1]
    game.close()
    assert [e["generation"] for e in run.curve] == [1, 2]
    assert all(e["worst"] <= e["mean"] <= e["best"] for e in run.curve)
    assert random_returns.mean() <= 0.25
    assert run.best_fitness >= 2.0
    assert run.curve[-1]["eval_return"] >= random_returns.mean() + 1.0


def test_diagonal_cma_es_state_grows_linearly_with_the_dimension():
    """A Boxing controller on [z h] has D = 4,914: the full strategy would pickle two D x D
    matrices (~390 MB); the separable one stays small and samples with a diagonal covariance."""
    strategy = new_strategy(4914, ControllerConfig(population=8, diagonal=True))
    assert len(pickle.dumps(strategy)) < 5_000_000
    candidates = np.array(strategy.ask())
    strategy.tell(list(candidates), list(np.arange(8.0)))
    assert strategy.sm.variances.shape == (4914,)


def test_a_checkpoint_from_before_a_config_field_existed_resumes(tmp_path):
    """Fields added to ControllerConfig later (e.g. ``diagonal``) take their defaults on resume."""
    sokoban_run(tmp_path, 1)
    saved = pickle.loads((tmp_path / "controller.pkl").read_bytes())
    del saved["config"]["diagonal"]
    (tmp_path / "controller.pkl").write_bytes(pickle.dumps(saved))
    assert len(sokoban_run(tmp_path, 2).curve) == 2
    with pytest.raises(ConfigMismatch, match="diagonal"):
        sokoban_run(tmp_path, 3, diagonal=True)


def sokoban_run(tmp_path, generations, **changes):
    cfg = for_profile(ControllerConfig, "smoke", generations=generations, max_steps=15, **changes)
    return train_controller("sokoban-small", grid, tiny_memory(25, 8), cfg, out_dir=tmp_path,
                            env_options=dict(observation="grid"), progress=False)


def test_resumed_run_reaches_the_same_result(tmp_path):
    straight = sokoban_run(tmp_path / "straight", 2)
    sokoban_run(tmp_path / "resumed", 1)
    resumed = sokoban_run(tmp_path / "resumed", 2)
    assert len(resumed.curve) == 2
    drop_time = lambda curve: [{k: v for k, v in e.items() if k != "seconds"} for e in curve]  # noqa: E731
    assert drop_time(resumed.curve) == drop_time(straight.curve)
    assert np.array_equal(resumed.mean_params, straight.mean_params)
    assert np.array_equal(resumed.best_params, straight.best_params)
    saved = load_run(tmp_path / "resumed")
    assert saved.generation == 2 and np.array_equal(saved.mean_params, straight.mean_params)
    curve = json.loads((tmp_path / "resumed" / "curve.json").read_text())["curve"]
    assert drop_time(curve) == drop_time(straight.curve)
    assert saved.controller("best").num_parameters == len(saved.best_params)
    plot_learning_curve(curve)


def test_resuming_with_a_changed_config_fails_clearly(tmp_path):
    sokoban_run(tmp_path, 1)
    with pytest.raises(ConfigMismatch, match=r"population.*\(8, 4\).*only generations may change"):
        sokoban_run(tmp_path, 2, population=4)


def test_dream_training_runs_in_the_memory_and_is_scored_in_the_real_game(tmp_path):
    cfg = for_profile(ControllerConfig, "smoke", dream=True, temperature=1.2, max_steps=15)
    run = train_controller("sokoban-small", grid, tiny_memory(25, 8), cfg, out_dir=tmp_path,
                           env_options=dict(observation="grid"), progress=False)
    assert [e["agent_steps"] for e in run.curve] == [30, 60]  # only the real-game evaluations
    assert all("eval_return" in e for e in run.curve)


def test_dream_stops_when_the_memory_predicts_done():
    memory = tiny_memory(4, 3)
    params = random_params(2, memory)
    with torch.no_grad():
        memory.done.weight.zero_()
        memory.done.bias.fill_(5.0)  # P(done) > 0.5 at once
        memory.reward.weight.zero_()
        memory.reward.bias.fill_(1.5)
    returns, steps = dream_population(params, memory, torch.zeros(3, 4), max_steps=10,
                                      generator=torch.Generator().manual_seed(0))
    assert returns.shape == (2, 3) and np.allclose(returns, 1.5) and np.all(steps == 1)


def test_a_corrupt_controller_checkpoint_is_named_in_a_clear_error(tmp_path):
    path = tmp_path / "controller.pkl"
    path.write_bytes(pickle.dumps({"format": "something else"})[:-3])
    with pytest.raises(ValueError, match="controller.pkl is truncated or corrupt"):
        load_run(path)
    path.write_bytes(pickle.dumps([1, 2]))  # whole, but not a checkpoint
    with pytest.raises(ValueError, match="is not a"):
        load_run(path)


def boxing_curve(seed: int) -> list[dict]:
    cfg = for_profile(ControllerConfig, "smoke", seed=seed, generations=2, max_steps=40)
    run = train_controller("boxing", pooled, tiny_memory(16, 18), cfg, progress=False)
    return [{k: v for k, v in e.items() if k != "seconds"} for e in run.curve]


def test_a_seed_repeats_its_boxing_curve_and_another_seed_draws_another():
    """On one CPU with one torch thread (the fixture), the same seed gives the same curve, to the
    last digit of every fitness; another seed gives other candidates and starts."""
    first, again, other = boxing_curve(3), boxing_curve(3), boxing_curve(4)
    assert first == again
    assert [e["mean"] for e in first] != [e["mean"] for e in other]


def test_a_checkpoint_of_another_dimension_is_refused_naming_the_file_and_the_sizes(tmp_path):
    sokoban_run(tmp_path, 1)
    cfg = for_profile(ControllerConfig, "smoke", generations=2, max_steps=15)
    with pytest.raises(ConfigMismatch, match=rf"{tmp_path / 'controller.pkl'}.*'task.hidden_size': \(8, 4\)"):
        train_controller("sokoban-small", grid, Memory(25, 8, hidden_size=4, n_gaussians=2).eval(), cfg,
                         out_dir=tmp_path, env_options=dict(observation="grid"), progress=False)


def test_mirrored_candidates_come_in_antithetic_pairs_and_a_mirrored_run_resumes_to_the_same_result(tmp_path):
    strategy = new_strategy(30, ControllerConfig(population=8, diagonal=True, mirrored=True))
    for generation in range(3):
        steps = np.array(strategy.ask()) - np.asarray(strategy.mean)
        assert np.allclose(steps[0::2], -steps[1::2])
        strategy.tell(list(steps + strategy.mean), list(np.random.default_rng(generation).normal(size=8)))
    straight = sokoban_run(tmp_path / "straight", 2, mirrored=True, diagonal=True)
    sokoban_run(tmp_path / "resumed", 1, mirrored=True, diagonal=True)
    resumed = sokoban_run(tmp_path / "resumed", 2, mirrored=True, diagonal=True)
    assert np.array_equal(resumed.mean_params, straight.mean_params)
    assert [e["mean"] for e in resumed.curve] == [e["mean"] for e in straight.curve]
