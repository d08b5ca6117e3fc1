"""The search's memory trained on the expert's games too (the ``own-memory`` variant, beyond the
thesis; MuZero's lever: a model learns the states its search goes to).

World Models + AlphaZero learns its deterministic memory from random play, where the player is
mostly hit; the search plans for an agent that imitates the World Models controller and mostly
hits. Along the agent's own games the memory's latent error grows with the depth of the search
(``metrics.json``'s ``diagnosis.reward_error.latent_mse``), and more simulations exploit what it
gets wrong (``docs/findings/planning-budget.md``). Here the expert (notebook 02's controller)
first plays ``memory_games`` greedy bouts, seeded from ``(seed, 7, k)``; a fresh memory then
learns from the random rollouts and those bouts together, and the search runs in it.

    folder = memory_folder(work, config)         # where that memory and its latents live
    memory, history = train_expert_memory(make_env, expert, vision, memory, latents, work, memory_cfg, config, seed)
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

from wmthesis.alphazero.imitation import expert_games
from wmthesis.alphazero.latent_mdp import LatentMDP
from wmthesis.runs import atomic_path
from wmthesis.utils import derive_seeds
from wmthesis.world_models.train import LatentStore, train_memory

LATENTS_NAME = "latents-with-expert.h5"


def memory_folder(work: Path, config) -> Path:
    """The folder of the memory a run of ``config`` searches in: the experiment's seed folder
    ``work``, or, with ``config.memory_games``, its ``memory-expert-N`` subfolder."""
    return Path(work) if not config.memory_games else Path(work) / f"memory-expert-{config.memory_games}"


def expert_latents(latents_path: str | Path, games: list, out_path: str | Path, identity: dict) -> Path:
    """Write the random rollouts of ``latents_path`` followed by ``games`` (each a
    :class:`~wmthesis.alphazero.replay.Game`) as one latents file, in
    :func:`~wmthesis.world_models.train.encode_store`'s format, atomically; returns its path.

    A game's latents are its features' first L entries (the VAE's means); their ``logvar`` is the
    random rollouts' mean per dimension, so the memory samples them with the noise it learns the
    rollouts with. The games come last: the memory's validation episodes (the last tenth) are the
    expert's, so its early stopping keeps the memory best on the agent's kind of fight.
    """
    rollouts = LatentStore(latents_path)
    size = rollouts.latent_size
    mu = np.concatenate([rollouts.data["mu"].numpy()] + [g.features[:, :size] for g in games]).astype(np.float32)
    logvar = np.concatenate([rollouts.data["logvar"].numpy()] + [
        np.broadcast_to(rollouts.data["logvar"].numpy().mean(0), (len(g), size)) for g in games]).astype(np.float32)
    scalars = {"actions": [rollouts.data["actions"].numpy()], "rewards": [rollouts.data["rewards"].numpy()],
               "terminals": [rollouts.data["terminals"].numpy()]}
    for g in games:
        scalars["actions"].append(g.actions.astype(rollouts.data["actions"].numpy().dtype))
        scalars["rewards"].append(g.rewards.astype(rollouts.data["rewards"].numpy().dtype))
        terminals = np.zeros(len(g), bool)
        terminals[-1] = g.terminated
        scalars["terminals"].append(terminals.astype(rollouts.data["terminals"].numpy().dtype))
    ends = np.concatenate([rollouts.ends, rollouts.ends[-1] + np.cumsum([len(g) for g in games], dtype=np.int64)])
    with atomic_path(out_path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["identity"] = json.dumps(identity)
        f.create_dataset("mu", data=mu)
        f.create_dataset("logvar", data=logvar)
        for name, parts in scalars.items():
            f.create_dataset(name, data=np.concatenate(parts))
        f.create_dataset("episode_ends", data=ends)
    return Path(out_path)


def train_expert_memory(make_env: Callable, expert: Callable, vision: Callable, memory, latents_path: str | Path,
                        work: Path, memory_config, config, seed: int, progress: bool = True) -> tuple:
    """The memory of the ``own-memory`` variant: ``config.memory_games`` greedy bouts of
    ``expert(agent_seed)`` in ``make_env()`` (made only when the bouts are not cached yet), each of
    ``config.eval_max_steps`` steps and recorded through ``memory`` (the random-play memory: the
    games keep its h, only their z and actions are used), written beside the random rollouts of
    ``latents_path`` (:func:`expert_latents`); then a fresh memory of ``memory_config`` trained on
    both, seeded with ``seed``. Both are cached in :func:`memory_folder`; returns ``(memory, history)``."""
    folder = memory_folder(work, config)
    path = folder / LATENTS_NAME
    rollouts = LatentStore(latents_path)
    identity = {**rollouts.identity, "expert_games": config.memory_games, "max_steps": config.eval_max_steps,
                "seed": seed}
    if not (path.exists() and LatentStore(path).identity == identity):
        seeds = [int(derive_seeds(seed, 7, k)[0]) for k in range(config.memory_games)]
        env = make_env()
        try:
            games = expert_games(env, expert, vision, LatentMDP(memory), seeds, max_steps=config.eval_max_steps,
                                 progress=progress)
        finally:
            env.close()
        folder.mkdir(parents=True, exist_ok=True)
        expert_latents(latents_path, games, path, identity)
    return train_memory(path, folder, memory_config, n_actions=LatentMDP(memory).n_actions, seed=seed,
                        progress=progress)


def expert_steps(work: Path, config, latents_path: str | Path) -> int:
    """The real steps of the expert's bouts :func:`train_expert_memory` recorded (0 without them)."""
    if not config.memory_games:
        return 0
    return LatentStore(memory_folder(work, config) / LATENTS_NAME).num_steps - LatentStore(latents_path).num_steps


__all__ = ["LATENTS_NAME", "memory_folder", "expert_latents", "train_expert_memory", "expert_steps"]
