"""A trained World Models agent in one file, to ship and to play: the vision's encoder, the memory,
the controller (the CMA-ES mean) and what made them (configs, the task, the commit), with a format
version. About 5 MB for Boxing: the VAE's decoder stays behind (playing only encodes; it ships in a
file of its own, :mod:`wmthesis.world_models.decoder`, and decoding without it raises an error).

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

from wmthesis.runs import read_agent_file, save_agent_file
from wmthesis.world_models.config import MemoryConfig
from wmthesis.world_models.decoder import MissingDecoder
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


def encoder_state(vae: VAE) -> dict:
    """The VAE's weights without its decoder (playing only encodes): what an agent file keeps."""
    return {k: v for k, v in vae.state_dict().items() if not k.startswith("decoder.")}


def load_encoder(latent_size: int, encoder: dict, path: Path, bfloat16: bool = False) -> VAEVision:
    """The vision of an agent file at ``path`` from its :func:`encoder_state`; ValueError naming the
    file where the weights do not fit."""
    vae = VAE(latent_size)
    missing, unexpected = vae.load_state_dict(encoder, strict=False)
    if unexpected or any(not k.startswith("decoder.") for k in missing):
        raise ValueError(f"{path}: its encoder does not fit the VAE (missing {missing}, unexpected {unexpected})")
    vae.decoder = MissingDecoder(f"{path} keeps only the vision's encoder (playing only encodes): load it with "
                                 "wmthesis.load, which attaches the decoder.pt that ships beside it")
    return VAEVision(vae.eval(), bfloat16=bfloat16)


def write_agent_file(path: str | os.PathLike, form: str, version: int, vae: VAE, memory, memory_config: MemoryConfig,
                     **fields) -> Path:
    """An agent file at ``path``, written atomically: ``form`` and ``version``, ``vae``'s encoder,
    ``memory`` with its config, and ``fields`` (what else the agent plays with); returns the path."""
    return save_agent_file(path, form, version, latent_size=vae.latent_size, encoder=encoder_state(vae),
                           memory_config=dataclasses.asdict(memory_config), memory=memory.state_dict(), **fields)


def agent_memory(saved: dict):
    """The memory an agent file's dict (:func:`read_agent_file`) holds, in eval mode."""
    task = saved["task"]
    memory = make_memory(task["latent_size"], task["n_actions"], MemoryConfig(**saved["memory_config"]))
    memory.load_state_dict(saved["memory"])
    return memory.eval()


def save_agent(path: str | os.PathLike, vae: VAE, memory, run, memory_config: MemoryConfig,
               commit: str | None) -> Path:
    """Write the agent of a finished controller ``run`` (a
    :class:`~wmthesis.world_models.evolution.ControllerRun`) on ``vae`` and ``memory`` to ``path``
    atomically; returns the path."""
    return write_agent_file(path, FORMAT, FORMAT_VERSION, vae, memory, memory_config,
                            params=np.asarray(run.mean_params, np.float64), task=run.task, controller_config=run.config,
                            generation=run.generation, commit=commit)


def load_agent(path: str | os.PathLike) -> Agent:
    """The agent saved at ``path``; a missing, corrupt or foreign file raises an error naming it."""
    path = Path(path)
    saved = read_agent_file(path, "World Models", FORMAT, FORMAT_VERSION)
    info = {k: saved[k] for k in ("task", "controller_config", "memory_config", "generation", "commit")}
    vision = load_encoder(saved["latent_size"], saved["encoder"], path, bool(saved["task"].get("vision_bfloat16", False)))
    return Agent(vision, agent_memory(saved), saved["params"], info)


__all__ = ["Agent", "AGENT_NAME", "FORMAT", "FORMAT_VERSION", "save_agent", "load_agent", "encoder_state",
           "load_encoder", "write_agent_file", "agent_memory"]
