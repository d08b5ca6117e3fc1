"""A trained World Models agent in one file, to ship and to play: the vision's encoder, the memory,
the controller (the CMA-ES mean) and what made them (configs, the task, the commit), with a format
version. About 5 MB for Boxing: the VAE's decoder stays behind (playing only encodes).

    save_agent(path, vae, memory, run, memory_config, commit)
    agent = load_agent(path)         # .vision, .memory, .params, .info
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from wmthesis.runs import atomic_path
from wmthesis.world_models.config import MemoryConfig
from wmthesis.world_models.train import make_memory
from wmthesis.world_models.vision import VAE, VAEVision

FORMAT = "wmthesis-world-models-agent"
FORMAT_VERSION = 1
AGENT_NAME = "agent.pt"


class Agent(NamedTuple):
    """A loaded agent: ``vision`` (frames -> z, encoding as the controller was evolved: float32 or
    bfloat16), ``memory``, the controller's flat ``params`` (D,) and ``info`` (configs, task,
    generation, commit)."""
    vision: VAEVision
    memory: torch.nn.Module
    params: np.ndarray
    info: dict


def save_agent(path: str | os.PathLike, vae: VAE, memory, run, memory_config: MemoryConfig,
               commit: str | None) -> Path:
    """Write the agent of a finished controller ``run`` (a
    :class:`~wmthesis.world_models.evolution.ControllerRun`) on ``vae`` and ``memory`` to ``path``
    atomically; returns the path."""
    encoder = {k: v for k, v in vae.state_dict().items() if not k.startswith("decoder.")}
    saved = {"format": FORMAT, "version": FORMAT_VERSION, "latent_size": vae.latent_size, "encoder": encoder,
             "memory_config": dataclasses.asdict(memory_config), "memory": memory.state_dict(),
             "params": np.asarray(run.mean_params, np.float64), "task": run.task, "controller_config": run.config,
             "generation": run.generation, "commit": commit}
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(saved, tmp)
    return path


def load_agent(path: str | os.PathLike) -> Agent:
    """The agent saved at ``path``; a missing, corrupt or foreign file raises an error naming it."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no World Models agent at {path}")
    try:
        saved = torch.load(path, weights_only=False, map_location="cpu")
        stamp = (saved.get("format"), saved.get("version"))
    except Exception as error:  # truncated, or not a torch file
        raise ValueError(f"cannot read {path}: {error}") from error
    if stamp != (FORMAT, FORMAT_VERSION):
        raise ValueError(f"{path} is not a {FORMAT} file of version {FORMAT_VERSION} (it says {stamp})")
    vae = VAE(saved["latent_size"])
    missing, unexpected = vae.load_state_dict(saved["encoder"], strict=False)
    if unexpected or any(not k.startswith("decoder.") for k in missing):
        raise ValueError(f"{path}: its encoder does not fit the VAE (missing {missing}, unexpected {unexpected})")
    task = saved["task"]
    memory = make_memory(task["latent_size"], task["n_actions"], MemoryConfig(**saved["memory_config"]))
    memory.load_state_dict(saved["memory"])
    info = {k: saved[k] for k in ("task", "controller_config", "memory_config", "generation", "commit")}
    return Agent(VAEVision(vae.eval(), bfloat16=bool(task.get("vision_bfloat16", False))), memory.eval(),
                 saved["params"], info)


__all__ = ["Agent", "AGENT_NAME", "FORMAT", "FORMAT_VERSION", "save_agent", "load_agent"]
