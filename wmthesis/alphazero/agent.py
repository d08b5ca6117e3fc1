"""A trained World Models + AlphaZero agent in one file, to ship and to play: the vision's encoder,
the deterministic memory the search runs in, the search's heads (and its reward model where the
variant learned one), the config and the task, the commit, with a format version. About 2 MB in
``quick``: the VAE's decoder, the optimiser and the replay stay behind. A file may name the World
Models agent whose encoder it shares (``vision_file``, with its SHA-256) in place of a copy
(:func:`share_vision`: the shipped agents of a seed share one vision).

    save_agent(path, vae, memory, run, memory_config, commit)
    agent = load_agent(path)
    mind = agent.mind()              # an AlphaZeroMind with the run's own search settings
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import NamedTuple

from wmthesis.alphazero.config import AlphaZeroConfig
from wmthesis.alphazero.heads import AlphaZeroHeads, Evaluator
from wmthesis.alphazero.latent_mdp import LatentMDP, RewardModel
from wmthesis.alphazero.selfplay import AlphaZeroMind
from wmthesis.runs import file_sha256, read_agent_file, save_agent_file
from wmthesis.world_models.agent import FORMAT as WM_FORMAT, FORMAT_VERSION as WM_VERSION
from wmthesis.world_models.agent import agent_memory, load_encoder, write_agent_file
from wmthesis.world_models.config import MemoryConfig
from wmthesis.world_models.vision import VAE, VAEVision

FORMAT = "wmthesis-alphazero-agent"
FORMAT_VERSION = 1


def agent_name(variant: str) -> str:
    """The agent file of ``variant``'s run, in the experiment's seed folder."""
    return f"agent-{variant}.pt"


class Agent(NamedTuple):
    """A loaded agent: ``vision`` (frames -> z), ``mdp`` (the memory, with the run's reward model
    where it has one), ``heads``, ``config`` (the run's :class:`AlphaZeroConfig`) and ``info``
    (variant, task, games, commit)."""
    vision: VAEVision
    mdp: LatentMDP
    heads: AlphaZeroHeads
    config: AlphaZeroConfig
    info: dict

    def mind(self, simulations: int | None = None, **changes) -> AlphaZeroMind:
        """The agent as it searched in its evaluation games (``simulations``: another budget;
        ``changes``: other :class:`AlphaZeroConfig` fields, e.g. ``root="gumbel"``)."""
        if simulations is not None:
            changes["simulations"] = simulations
        return AlphaZeroMind(self.vision, self.mdp, Evaluator(self.heads), dataclasses.replace(self.config, **changes))


def save_agent(path: str | os.PathLike, variant: str, vae: VAE, memory, run, memory_config: MemoryConfig,
               commit: str | None) -> Path:
    """Write the agent of ``variant``'s self-play ``run`` (an
    :class:`~wmthesis.alphazero.selfplay.AlphaZeroRun`) searching in ``memory`` (the deterministic
    memory of ``memory_config``), seeing through ``vae``, to ``path`` atomically; returns the path."""
    return write_agent_file(path, FORMAT, FORMAT_VERSION, vae, memory, memory_config, variant=variant,
                            heads=run.heads.state_dict(), config=run.config, task=run.task, games=run.games,
                            reward_model=None if run.reward_model is None else run.reward_model.state_dict(),
                            commit=commit)


def load_agent(path: str | os.PathLike) -> Agent:
    """The agent saved at ``path``; a missing, corrupt or foreign file raises an error naming it."""
    path = Path(path)
    saved = read_agent_file(path, "World Models + AlphaZero", FORMAT, FORMAT_VERSION)
    task, config = saved["task"], AlphaZeroConfig(**{**dataclasses.asdict(AlphaZeroConfig()), **saved["config"]})
    heads = AlphaZeroHeads(task["latent_size"], task["hidden_size"], task["n_actions"])
    heads.load_state_dict(saved["heads"])
    reward_model = None
    if saved["reward_model"] is not None:
        reward_model = RewardModel(task["latent_size"] + task["hidden_size"], task["n_actions"], config.reward_hidden,
                                   config.reward_range)
        reward_model.load_state_dict(saved["reward_model"])
    info = {k: saved[k] for k in ("variant", "task", "games", "commit")}
    return Agent(load_encoder(saved["latent_size"], shared_encoder(saved, path), path),
                 LatentMDP(agent_memory(saved), reward_model), heads.eval(), config, info)


def shared_encoder(saved: dict, path: Path) -> dict:
    """The encoder weights an agent file holds, or those of the World Models agent file it names
    (``vision_file``: the path beside it and its SHA-256, checked); ValueError naming both where
    that file is missing or has changed."""
    if saved.get("vision_file") is None:
        return saved["encoder"]
    vision = path.parent / saved["vision_file"]["path"]
    if not vision.is_file() or file_sha256(vision) != saved["vision_file"]["sha256"]:
        raise ValueError(f"{path} sees through the vision of {vision}, which is "
                         f"{'missing' if not vision.is_file() else 'not the file it was trained with (its SHA-256 differs)'}")
    return read_agent_file(vision, "World Models", WM_FORMAT, WM_VERSION)["encoder"]


def share_vision(path: str | os.PathLike, vision: str | os.PathLike) -> Path:
    """Rewrite the agent file at ``path`` to name the World Models agent file ``vision`` in place of
    its own copy of the same encoder (ValueError where the encoders differ); nothing else changes."""
    import torch

    path, vision = Path(path), Path(vision)
    saved = read_agent_file(path, "World Models + AlphaZero", FORMAT, FORMAT_VERSION)
    theirs = read_agent_file(vision, "World Models", WM_FORMAT, WM_VERSION)["encoder"]
    ours = shared_encoder(saved, path)
    if ours.keys() != theirs.keys() or not all(torch.equal(ours[k], theirs[k]) for k in ours):
        raise ValueError(f"{path} does not see through the encoder of {vision}")
    fields = {k: v for k, v in saved.items() if k not in ("format", "version")}
    fields.update(encoder=None, vision_file={"path": os.path.relpath(vision, path.parent), "sha256": file_sha256(vision)})
    return save_agent_file(path, FORMAT, FORMAT_VERSION, **fields)


__all__ = ["Agent", "FORMAT", "FORMAT_VERSION", "agent_name", "save_agent", "load_agent", "shared_encoder", "share_vision"]
