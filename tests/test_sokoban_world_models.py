"""World Models on Sokoban (thesis 5.3): 64x64 frames, grid-state latents (5.3.2), the Sokoban
open-loop measures, random play on the same levels, and the `sokoban-wm` experiment end to end."""
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from wmthesis.data import EpisodeStore
from wmthesis.rollouts import collect
from wmthesis.envs import make_env
from wmthesis.envs.sokoban import BOX, FLOOR, PLAYER, TARGET, grid_frames, read_grid, solve
from wmthesis.envs.vector import ListGame, make_game
from wmthesis.experiments import EXPERIMENTS, sokoban_wm_configs
from wmthesis.world_models.evolution import random_play
from wmthesis.world_models.grid import GRID_NOISE_STD, GridVision, decode_grid, encode_grid_store, grid_accuracy
from wmthesis.world_models.memory import Memory
from wmthesis.world_models.prediction import head_predictions, open_loop, open_loop_grid, rollout_latents
from wmthesis.world_models.sokoban import head_numbers, levels_solved
from wmthesis.world_models.train import LatentStore
from wmthesis.world_models.vision import VAE

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py


def rollout(seed, steps=30, **options):
    """Observations of one seeded level under a fixed action sequence (pushes and moves)."""
    env = make_env("sokoban", **options)
    observation, _ = env.reset(seed=seed)
    observations = [observation]
    for action in np.random.default_rng(seed).integers(8, size=steps):
        observation, *_ = env.step(int(action))
        observations.append(observation)
    return np.stack(observations), env


@pytest.mark.parametrize("seed", [0, 7])
def test_world_models_frames_are_the_render_without_its_wall_ring_resized_by_cv2(seed):
    frames, env = rollout(seed, frame_size=64)
    raw, _ = rollout(seed)
    assert frames.shape == (31, 64, 64, 3) and frames.dtype == np.uint8
    assert env.observation_space.shape == (64, 64, 3) and env.observation_space.contains(frames[0])
    expected = [cv2.resize(np.ascontiguousarray(frame[16:-16, 16:-16]), (64, 64), interpolation=cv2.INTER_AREA)
                for frame in raw]
    assert np.array_equal(frames, np.stack(expected))
    assert len({frame.tobytes() for frame in frames}) > 1  # the player moved: frames follow the game


def test_frame_size_needs_rgb_observations():
    with pytest.raises(ValueError, match="frame_size"):
        make_env("sokoban", observation="grid", frame_size=64)


@pytest.mark.parametrize("name, inner", [("sokoban", (8, 8)), ("sokoban-small", (5, 5))])
def test_grid_states_and_frames_convert_both_ways(name, inner):
    env_frames, env_grids = make_env(name, frame_size=64), make_env(name, observation="grid")
    for seed in range(3):
        frame, _ = env_frames.reset(seed=seed)
        grid, _ = env_grids.reset(seed=seed)
        assert grid.shape == (inner[0] * inner[1],)
        assert np.array_equal(grid, env_grids.board[1:-1, 1:-1].ravel())
        assert np.array_equal(grid_frames(grid[None], inner)[0], frame)
        assert np.array_equal(read_grid(frame, inner), grid)
    # Reading is robust to the blur of a decoded prediction, and sees a changed cell.
    noisy = np.clip(frame.astype(int) + np.random.default_rng(0).integers(-40, 41, frame.shape), 0, 255)
    assert np.array_equal(read_grid(noisy.astype(np.uint8), inner), grid)
    changed = grid.copy()
    first_floor = int(np.flatnonzero(grid == FLOOR)[0])
    changed[first_floor] = BOX
    assert np.flatnonzero(read_grid(grid_frames(changed[None], inner), inner)[0] != grid).tolist() == [first_floor]


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sokoban")
    rgb = collect("sokoban", 3, folder / "rgb.h5", seed=5, max_steps=25, progress=False, frame_size=64)
    grid = collect("sokoban", 3, folder / "grid.h5", seed=5, max_steps=25, progress=False, observation="grid")
    return folder, rgb, grid


def test_frame_and_grid_stores_hold_the_same_episodes(stores):
    _, rgb, grid = stores
    with EpisodeStore(rgb) as frames, EpisodeStore(grid) as grids:
        assert frames.obs_shape == (64, 64, 3) and grids.obs_shape == (64,)
        for index in range(3):
            a, b = frames.episode(index), grids.episode(index)
            assert np.array_equal(a["actions"], b["actions"]) and np.array_equal(a["rewards"], b["rewards"])
            assert np.array_equal(read_grid(a["observations"]), b["observations"])


def test_grid_latents_are_the_block_codes(stores):
    folder, _, grid = stores
    path = encode_grid_store(grid, folder / "latents-grid.h5")
    latents = LatentStore(path)
    with EpisodeStore(grid) as store:
        codes = np.concatenate([store.episode(i)["observations"] for i in range(3)])
        actions = np.concatenate([store.episode(i)["actions"] for i in range(3)])
    assert latents.latent_size == 64 and len(latents) == 3 and latents.identity["latent"] == "grid"
    assert np.array_equal(latents.data["mu"].numpy(), codes.astype(np.float32))
    assert np.allclose(latents.data["logvar"].numpy(), 2 * np.log(GRID_NOISE_STD))
    assert np.array_equal(latents.data["actions"].numpy(), actions)
    # z ~ N(codes, 0.1^2), as the memory trains on, decodes back to the codes.
    noise = torch.randn(latents.data["mu"].shape, generator=torch.Generator().manual_seed(0))
    z = latents.data["mu"] + GRID_NOISE_STD * noise
    assert (decode_grid(z) == codes).mean() > 0.999
    assert decode_grid(np.array([-3.0, 0.4, 2.6, 9.0])).tolist() == [0, 0, 3, 6]
    stamp = path.stat().st_mtime_ns
    assert encode_grid_store(grid, path) == path and path.stat().st_mtime_ns == stamp  # kept
    with pytest.raises(ValueError, match="grid observations"):
        encode_grid_store(stores[1], folder / "wrong.h5")
    assert torch.equal(GridVision()(torch.from_numpy(codes[:2])), torch.from_numpy(codes[:2]).float())


def test_open_loop_on_latents_matches_the_frame_open_loop(stores):
    _, rgb, grid = stores
    torch.manual_seed(0)
    vae, memory = VAE(16).eval(), Memory(16, 8, hidden_size=32).eval()
    with EpisodeStore(rgb) as store:
        episode = store.episode(0)
    result = open_loop(vae, memory, episode["observations"], episode["actions"], context=10, horizon=8)
    with torch.no_grad():
        mu, _ = vae.encode(torch.from_numpy(episode["observations"]).movedim(-1, -3).float() / 255)
        latents = rollout_latents(memory, mu, torch.from_numpy(episode["actions"]), 10, 8)
        decoded = (vae.decode(latents).clamp(0, 1) * 255).round().to(torch.uint8).movedim(-3, -1).numpy()
    assert np.array_equal(decoded, result["prediction"])

    grid_memory = Memory(64, 8, hidden_size=32).eval()
    with EpisodeStore(grid) as store:
        codes = store.episode(0)
    out = open_loop_grid(grid_memory, codes["observations"], codes["actions"], context=10, horizon=8)
    assert out["prediction"].shape == out["truth"].shape == (8, 64, 64, 3)
    assert np.array_equal(out["truth"], episode["observations"][10:18])  # drawn grids = the env's frames
    assert np.array_equal(read_grid(out["prediction"]), out["prediction_grid"])
    assert np.isclose(out["pixel_error"][0], np.mean((out["truth"][0] / 255 - out["prediction"][0] / 255) ** 2))


def test_grid_accuracy_counts_what_the_eye_saw():
    truth = np.full((1, 2, 4), FLOOR, np.uint8)
    truth[0, :, 0] = PLAYER
    truth[0, :, 1] = BOX
    last_seen = truth[0, 0].copy()
    truth[0, 1, 0], truth[0, 1, 2] = FLOOR, PLAYER  # the player moved two cells right at step 2
    predicted = truth.copy()
    predicted[0, 1, 2] = FLOOR                       # ... and vanished from the prediction
    predicted[0, 0, 1] = TARGET                      # a box turned into a target at step 1
    out = grid_accuracy(predicted, truth, last_seen[None], num_boxes=1)
    assert out["cell_accuracy"].tolist() == [0.75, 0.75]
    assert np.isnan(out["changed_cell_accuracy"][0]) and out["changed_cell_accuracy"][1] == 0.5
    assert out["one_player"].tolist() == [1.0, 0.0] and out["boxes_kept"].tolist() == [0.0, 1.0]


def test_random_play_is_seeded_and_plays_the_given_levels():
    seeds = np.array([3, 4, 5])
    game = make_game("sokoban", 3, observation="grid")
    returns, steps = random_play(game, seeds, seed=1, max_steps=40)
    again, _ = random_play(game, seeds, seed=1, max_steps=40)
    assert isinstance(game, ListGame) and np.array_equal(returns, again) and steps.tolist() == [40, 40, 40]
    rng = np.random.default_rng(1)  # the same draws, played one env at a time
    actions = rng.integers(8, size=(40, 3))
    for k, seed in enumerate(seeds):
        env = make_env("sokoban", observation="grid")
        env.reset(seed=int(seed))
        assert np.isclose(sum(env.step(int(a))[1] for a in actions[:, k]), returns[k])
    game.close()


def test_solved_counts_the_levels_whose_return_holds_the_bonus():
    env = make_env("sokoban", observation="grid")
    env.reset(seed=2)
    actions = solve(env.board.copy())
    total, done = 0.0, False
    for action in actions:
        _, reward, done, _, _ = env.step(action)
        total += reward
    assert done and levels_solved([total], [len(actions)]) == 1
    assert levels_solved([-12.0, -10.0 + 3.0], [120, 100]) == 0  # step costs, three boxes on targets
    assert levels_solved([total, -12.0], [len(actions), 120]) == 1


def test_head_numbers_against_a_constant():
    true = np.array([-0.1, -0.1, 0.9, -0.1, -1.1])
    perfect = head_numbers(true, true, constant=-0.1, events=np.abs(true + 0.1) > 1e-3)
    assert perfect["mse"] == 0 and perfect["skill"] == 1 and perfect["events"] == 2
    assert np.isclose(perfect["event_constant_mse"], 1.0)
    constant = head_numbers(np.full(5, true.mean()), true, constant=true.mean())
    assert constant["skill"] == 0 and np.isnan(constant["correlation"])
    memory = Memory(4, 8, hidden_size=8, auxiliary=True)
    heads = head_predictions(memory, np.zeros((6, 4)), np.zeros(6, np.int64))
    assert heads["reward"].shape == heads["value"].shape == (6,)


def test_thesis_profile_fits_sokoban_episodes_and_quick_collects_more():
    assert sokoban_wm_configs("thesis")["memory"].sequence_length + 1 <= 120
    assert sokoban_wm_configs("quick", seed=3)["collect"].episodes == 400
    assert sokoban_wm_configs("quick", seed=3)["controller"].seed == 3


@pytest.fixture(scope="module")
def smoke_metrics():
    from wmthesis.experiments import reproduce

    return reproduce("sokoban-wm", "smoke", seed=0, progress=False)


def test_smoke_experiment_writes_every_variant(smoke_metrics):
    m = smoke_metrics
    out = Path(m["files"]["recording"]).parent
    assert json.loads((out / "metrics.json").read_text())["memory"].keys() == m["memory"].keys()
    assert set(m["memory"]) == {"mdn", "deterministic", "auxiliary", "grid", "grid-auxiliary"}
    for variant, entry in m["memory"].items():
        assert np.isfinite(entry["best_val"]["val_loss"]) and np.isfinite(entry["best_val"]["val_latent"])
        assert len(entry["history"]) == 2 and entry["history"][-1]["step"] == 6
        curves = entry["open_loop"]
        assert len(curves["pixel_error"]) == len(curves["cell_accuracy"]) == 10
        assert 0 <= curves["at_cutoff"]["cell_accuracy"] <= 1 and np.isfinite(curves["at_cutoff"]["pixel_error"])
        assert ("value_head" in entry) == variant.endswith("auxiliary")
    # "Nothing moves" is exact at the first step for the cells that did not change.
    still = m["baselines"]["nothing moves"]
    assert still["cell_accuracy"][0] > 0.9 and still["one_player"] == [1.0] * 10
    assert m["baselines"]["vae reconstruction"]["pixel_error"][0] > 0
    for variant in ("mdn", "grid", "grid-auxiliary"):
        assert m["controllers"][variant]["score"]["episodes"] == 4 and m["controllers"][variant]["generations"] == 2
    assert m["score"] == m["controllers"]["mdn"]["score"]
    assert m["random_play"]["score"]["episodes"] == 4 and m["random_play"]["score"]["max"] <= 5
    for path in [*m["files"]["figures"], m["files"]["recording"]]:
        assert Path(path).stat().st_size > 1000, path


def test_command_line_reproduces_sokoban_and_resumes(smoke_metrics, capsys):
    from wmthesis.__main__ import main

    assert "sokoban-wm" in EXPERIMENTS
    work = Path(os.environ["WMTHESIS_DATA"], "smoke", "sokoban-wm", "seed0")
    checkpoints = sorted(work.glob("**/*.pt")) + sorted(work.glob("**/controller.pkl"))
    stamps = [p.stat().st_mtime_ns for p in checkpoints]
    assert len(checkpoints) >= 1 + 2 * 5 + 3
    assert main(["reproduce", "sokoban-wm", "--profile", "smoke"]) == 0
    assert f"score {smoke_metrics['score']['mean']:.1f}" in capsys.readouterr().out
    assert [p.stat().st_mtime_ns for p in checkpoints] == stamps  # nothing retrained
    # written again by a call that trains nothing: the time it states for a run from scratch counts the sittings before it
    saved = Path(smoke_metrics["files"]["recording"]).parent / "metrics.json"
    saved.unlink()
    assert main(["reproduce", "sokoban-wm", "--profile", "smoke"]) == 0
    again = json.loads(saved.read_text())
    evolved = sum(g["seconds"] for c in smoke_metrics["controllers"].values() for g in c["curve"])
    assert evolved > 0 and again["first_run_wall_seconds"] > again["wall_seconds"] + 0.5 * evolved
    assert [p.stat().st_mtime_ns for p in checkpoints] == stamps
    assert main(["reproduce", "sokoban-wm", "--variant", "grid", "--profile", "smoke"]) == 2
    assert "has no variants" in capsys.readouterr().err
