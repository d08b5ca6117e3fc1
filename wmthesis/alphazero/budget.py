"""The search's budget curve on a loaded agent (an :class:`~wmthesis.alphazero.trained.AlphaZeroAgent`):
its policy head alone, then its search at each number of simulations and with each root, on the
same bouts of a split (:func:`~wmthesis.alphazero.evaluation.bout_seeds`). Each game is saved as it
ends, keyed by the agent file's SHA-256 and the search's settings, so a curve cut off midway plays
only the (budget, bout) pairs not yet saved. :func:`search_changes` reads from the played games
where the search moved the head's action and what those steps earned.

    agent = wmthesis.load("boxing-wm-alphazero", seed=3)
    head = head_games(agent, "validation", 10, folder)
    games = searched_games(agent, 16, "validation", 10, folder, root="gumbel")
    search_changes(agent.heads, games)          # {"changed": 0.31, "return_changed": ..., ...}
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch

from wmthesis.alphazero.evaluation import bout_seeds, cached_games, head_returns, resumed_games
from wmthesis.alphazero.variants import VARIANTS
from wmthesis.declarations import NAMES
from wmthesis.runs import built_on, file_sha256, read_json, write_json

STEPS_AHEAD = 10  # a step's real return in :func:`search_changes`: its reward and the next 9


def alphazero_agent(profile: str, seed: int, variant: str | None, progress: bool):
    """``boxing-wm-alphazero``'s loaded agent of ``variant`` (default: the default), trained first
    where its file is not there."""
    from wmthesis.agents import load

    name = VARIANTS.check(variant).name
    try:
        return load(NAMES.boxing_wm_alphazero, variant=name, profile=profile, seed=seed)
    except FileNotFoundError:
        built_on(NAMES.boxing_wm_alphazero, profile, seed, name, progress)
        return load(NAMES.boxing_wm_alphazero, variant=name, profile=profile, seed=seed)


def search_key(agent, split: str, bouts: int, **search) -> dict:
    """What a curve's games depend on: the agent file's SHA-256, the bouts' seeds and ``search``
    (``simulations``, ``root`` and the root's settings, ``None`` where the agent's own)."""
    return {"agent": file_sha256(agent.path), "seeds": bout_seeds(split, agent.seed, bouts, agent.config.noop_max),
            "max_steps": agent.config.eval_max_steps, **search}


def _cache_path(folder: Path, split: str, key: dict) -> Path:
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
    return Path(folder) / f"{split}-{key.get('root') or 'own'}-{key.get('simulations', 0)}-{digest}"


def head_games(agent, split: str, bouts: int, folder: Path) -> dict:
    """The policy head played greedily without search on ``bouts`` games of ``split``: ``returns``
    and ``ms_per_action`` (encoding, head and emulator together); cached in ``folder``."""
    key = search_key(agent, split, bouts)
    path = _cache_path(folder, split, key).with_suffix(".json")
    cached = read_json(path)
    if cached is not None and cached["key"] == key:
        return cached
    result = {"key": key, **head_returns(agent.vision, agent.memory, agent.heads, agent.env(), key)}
    write_json(path, result)
    return result


def searched_games(agent, simulations: int, split: str, bouts: int, folder: Path, progress: bool = False,
                   **root) -> list:
    """``bouts`` greedy games of ``split`` with the agent's search at ``simulations`` an action
    and ``root`` (:data:`~wmthesis.alphazero.config.SEARCH_FIELDS` of
    :class:`~wmthesis.alphazero.config.AlphaZeroConfig` in place of the agent's own); each
    :class:`~wmthesis.alphazero.replay.Game` saved as it ends in ``folder``."""
    key = search_key(agent, split, bouts, simulations=int(simulations), **root)
    path = _cache_path(folder, split, key).with_suffix(".pkl")
    done = cached_games(path, key)
    if done is not None:
        return done
    return resumed_games(path, key, agent.loaded.mind(int(simulations), **root), agent.env(), progress=progress,
                         desc=f"{simulations} simulations")


@torch.inference_mode()
def head_actions(heads, features: np.ndarray) -> np.ndarray:
    """The policy head's greedy action on each root's features (T, F) -> (T,)."""
    logits, _ = heads(torch.as_tensor(features, dtype=torch.float32))
    return logits.argmax(-1).numpy()


def steps_ahead_returns(rewards: np.ndarray, steps: int = STEPS_AHEAD) -> np.ndarray:
    """Each step's real reward summed with the next ``steps - 1`` (T,) -> (T,), fewer at the end."""
    cumulative = np.concatenate([[0.0], np.cumsum(rewards, dtype=np.float64)])
    ends = np.minimum(np.arange(len(rewards)) + steps, len(rewards))
    return cumulative[ends] - cumulative[:-1]


def search_changes(heads, games: list, steps: int = STEPS_AHEAD) -> dict:
    """Where the search moved the policy head's action, read from ``games`` played with it:
    ``changed``, the share of steps whose action is not the head's greedy action on the same root;
    ``return_changed`` and ``return_kept``, the mean real return over the ``steps`` steps from
    each such step and from the others (None where there is none)."""
    changed, ahead = [], []
    for game in games:
        changed.append(game.actions != head_actions(heads, game.features))
        ahead.append(steps_ahead_returns(game.rewards, steps))
    changed, ahead = np.concatenate(changed), np.concatenate(ahead)
    mean = lambda x: float(x.mean()) if len(x) else None
    return {"changed": float(changed.mean()), "return_changed": mean(ahead[changed]), "return_kept": mean(ahead[~changed])}


__all__ = ["alphazero_agent", "STEPS_AHEAD", "search_key", "head_games", "searched_games", "head_actions", "steps_ahead_returns",
           "search_changes"]
