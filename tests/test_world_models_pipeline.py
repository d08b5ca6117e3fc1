"""The World Models pipeline on real (short) Boxing episodes: vision, latents, memory, open loop."""
import dataclasses

import numpy as np
import pytest
import torch

from wmthesis.config import for_profile
from wmthesis.data import EpisodeStore
from wmthesis.rollouts import collect
from wmthesis.training import ConfigMismatch
from wmthesis.world_models.config import MemoryConfig, VisionConfig
from wmthesis.world_models.prediction import open_loop
from wmthesis.world_models.train import (LatentStore, encode_store, reconstruct, split_episodes, train_memory,
                                         train_vision)
from wmthesis.world_models.vision import VAE


@pytest.fixture(scope="module")
def boxing_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("wm") / "boxing.h5"
    return collect("boxing", 3, path, workers=1, seed=0, max_steps=100, progress=False)


@pytest.fixture(scope="module")
def trained(boxing_store, tmp_path_factory):
    run = tmp_path_factory.mktemp("run")
    config = for_profile(VisionConfig, "smoke", batch_size=32, steps=80, eval_every=20, patience=None, latent_size=8)
    vae, history = train_vision(boxing_store, run, config, progress=False)
    return run, vae, history


def test_split_keeps_the_last_episodes_for_validation():
    train, val = split_episodes(20, 0.1)
    assert list(val) == [18, 19] and list(train) == list(range(18))
    assert [list(s) for s in split_episodes(1, 0.1)] == [[0], [0]]
    assert [list(s) for s in split_episodes(2, 0.1)] == [[0], [1]]


def test_vision_reconstruction_error_falls_on_real_frames(trained, boxing_store):
    run, vae, history = trained
    losses = [h["val_reconstruction"] for h in history]
    assert len(losses) == 4 and losses[-1] < losses[0]  # Bernoulli NLL: its floor is the pixels' entropy
    with EpisodeStore(boxing_store) as store:
        frames = store.episode(2)["observations"][:16]  # a validation episode
    torch.manual_seed(0)
    untrained = VAE(8).eval()
    before = np.mean((frames / 255 - reconstruct(untrained, frames) / 255) ** 2)
    after = np.mean((frames / 255 - reconstruct(vae, frames) / 255) ** 2)
    assert after < 0.3 * before, (after, before)


def test_vision_refuses_a_store_of_another_env(trained, tmp_path):
    run, _, _ = trained
    freeway = collect("freeway", 2, tmp_path / "freeway.h5", workers=1, max_steps=20, progress=False)
    config = for_profile(VisionConfig, "smoke", batch_size=32, steps=80, eval_every=20, patience=None, latent_size=8)
    with pytest.raises(ConfigMismatch, match="freeway"):
        train_vision(freeway, run, config, progress=False)


def test_latents_and_memory(trained, boxing_store, tmp_path):
    run, vae, _ = trained
    path = encode_store(boxing_store, vae, tmp_path / "latents.h5", progress=False)
    latents = LatentStore(path)
    assert len(latents) == 3 and latents.data["mu"].shape == (300, 8)
    stamp = path.stat().st_mtime_ns
    assert encode_store(boxing_store, vae, path, progress=False) == path and path.stat().st_mtime_ns == stamp
    returns = latents.returns(0.5)
    rewards = latents.data["rewards"]
    assert torch.isclose(returns[98], rewards[98] + 0.5 * rewards[99]) and returns[99] == rewards[99]

    for kind in ("mdn", "deterministic"):
        config = for_profile(MemoryConfig, "smoke", kind=kind, auxiliary=True, steps=60, eval_every=10, lr=1e-2,
                             patience=None, sequence_length=20, batch_size=8)
        memory, history = train_memory(path, run, config, n_actions=18, progress=False)
        assert np.isfinite([h["val_loss"] for h in history]).all()
        assert len(history) == 6 and history[-1]["step"] == 60
        # (a barely trained VAE's latents are mostly noise; the memory's learning is tested on a
        # known mixture in tests/test_world_models.py)
    with EpisodeStore(boxing_store) as store:
        episode = store.episode(0)
    result = open_loop(vae, memory, episode["observations"], episode["actions"], context=20, horizon=10)
    assert result["prediction"].shape == result["truth"].shape == (10, 64, 64, 3)
    assert result["pixel_error"].shape == (10,) and np.isfinite(result["latent_error"]).all()
    assert result["pixel_error"].max() < 0.1  # decoded predictions look like Boxing frames ...
    from wmthesis.metrics import horizon_errors  # ... closer to them than a flat grey image (0.035) is
    grey = horizon_errors(result["truth"], np.full_like(result["truth"], 128))
    assert result["pixel_error"].mean() < 0.5 * grey.mean(), (result["pixel_error"].mean(), grey.mean())

    from wmthesis.world_models.prediction import open_loop_errors
    errors = open_loop_errors(vae, memory, episode, context=20, horizon=10, starts=8)
    assert errors["rollouts"] == 3  # 100 steps hold three spans of 30
    first = open_loop(vae, memory, episode["observations"][60:], episode["actions"][60:], context=20, horizon=10)
    assert errors["pixel_error"].shape == (10,) and errors["pixel_error"].max() < 0.1
    assert not np.allclose(errors["pixel_error"], first["pixel_error"])  # an average, not one rollout
    still = dict(episode, observations=np.repeat(episode["observations"][:1], 100, 0))
    assert np.all(open_loop_errors(vae, memory, still, context=20, horizon=10)["still_pixel_error"] == 0)
    with pytest.raises(ValueError, match="open loop needs context \\+ horizon = 30"):
        open_loop_errors(vae, memory, {k: v[:29] for k, v in episode.items()}, context=20, horizon=10)


def test_memory_resume_with_changed_config_fails(trained, boxing_store, tmp_path):
    run, vae, _ = trained
    path = encode_store(boxing_store, vae, tmp_path / "latents.h5", progress=False)
    config = for_profile(MemoryConfig, "smoke", steps=6)
    train_memory(path, tmp_path, config, n_actions=18, progress=False)
    with pytest.raises(ConfigMismatch, match="hidden_size"):
        train_memory(path, tmp_path, dataclasses.replace(config, hidden_size=64), n_actions=18, progress=False)


def test_boxing_wm_variants_share_the_world_model_and_each_evolves_in_a_folder_of_its_own(tmp_path):
    from wmthesis.experiments import reproduce
    from wmthesis.world_models.variants import BOXING_WM, ROOT, controller_config, controller_folder

    assert BOXING_WM.default.name in BOXING_WM and ROOT in BOXING_WM
    assert controller_folder(tmp_path, ROOT) == tmp_path / "controller"
    others = [name for name in BOXING_WM if name != ROOT]
    assert {controller_folder(tmp_path, name).name for name in others} == {f"controller-{name}" for name in others}
    for name in BOXING_WM:
        quick, smoke = controller_config("quick", 7, name), controller_config("smoke", 7, name)
        assert quick.seed == smoke.seed == 7
        assert all(getattr(quick, k) == v for k, v in BOXING_WM.changes(name).items())
        assert (smoke.population, smoke.generations) == (8, 2)  # a smoke run stays small
    with pytest.raises(ValueError, match=f"unknown variant 'nope' of boxing-wm; valid: {ROOT}"):
        reproduce("boxing-wm", "smoke", variant="nope")
