"""Learning inside the dream under a budget of real agent steps (beyond the thesis: World Models'
iterative procedure, Ha & Schmidhuber 2018; SimPLe's short model rollouts from real states,
Kaiser et al. 2019).

The procedure, top to bottom (:func:`learn_in_dream`):

1. Random play: ``random_bouts`` bouts into the store of real steps (half the budget at most).
2. The vision (VAE) learns the store's frames once; the memory (MDN-RNN) learns its latents.
3. While the budget lasts, an iteration:

   a. CMA-ES evolves the controller inside the dream for ``generations`` generations. Every
      candidate dreams from the same ``starts`` real states (a stretch of a stored bout: the
      memory warmed on ``warmup`` real steps), ``dream_length`` steps at ``temperature``; its
      fitness is the mean of the rewards the memory predicts (:func:`dream_starts`,
      :func:`~wmthesis.world_models.evolution.dream_population`).
   b. The CMA-ES mean plays ``bouts`` real bouts, which join the store: its real return beside
      its dream return is the iteration's gap between dream and reality.
   c. The memory fine-tunes on every real step so far (``memory_updates`` updates).

4. The controller kept is the iteration's mean whose real bouts scored best, with the memory it
   was evolved in (the bouts were played anyway: choosing costs no extra real step).

Every real step counts against the budget (:class:`Budget`): random play and every bout the
controller plays. A stage is capped to what is left, so a run never spends more.
"""
from __future__ import annotations

import copy
import dataclasses
import shutil
import time
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
import torch

from wmthesis.data import EpisodeStore
from wmthesis.envs.vector import make_game
from wmthesis.rollouts import collect
from wmthesis.runs import LOCK_NAME
from wmthesis.utils import derive_seeds
from wmthesis.world_models.config import DreamConfig, MemoryConfig, VisionConfig
from wmthesis.world_models.controller import num_parameters
from wmthesis.world_models.evolution import ControllerRun, dream_population, evaluate_population, new_strategy
from wmthesis.world_models.train import LatentStore, encode_store, train_memory, train_vision
from wmthesis.world_models.vision import VAEVision

GAME, N_ACTIONS = "boxing", 18


class BudgetExceeded(RuntimeError):
    """A stage asked for more real agent steps than the budget has left."""


class Budget:
    """The real agent steps a run may spend (``total``) and what each stage spent (``spent``)."""

    def __init__(self, total: int):
        if total < 1:
            raise ValueError(f"a budget of real agent steps must be positive, got {total}")
        self.total, self.spent = int(total), {}

    @property
    def used(self) -> int:
        return sum(self.spent.values())

    @property
    def remaining(self) -> int:
        return self.total - self.used

    def charge(self, stage: str, steps: int) -> None:
        """Count ``steps`` against ``stage``; :class:`BudgetExceeded` where fewer are left."""
        if steps > self.remaining:
            raise BudgetExceeded(f"{stage} spent {steps:,} real agent steps; {self.remaining:,} of {self.total:,} were left")
        self.spent[stage] = self.spent.get(stage, 0) + int(steps)


class Iteration(NamedTuple):
    """One iteration's record: the real steps spent when it ended, the CMA-ES mean's dream return
    (mean over its dreams of ``dream_length`` steps), its real bouts' returns and steps, and the
    seconds it took."""
    iteration: int
    real_steps: int
    dream_return: float
    real_returns: list
    real_steps_played: list
    seconds: float

    def record(self, dream_length: int) -> dict:
        """As plain data, with the real reward per ``dream_length`` steps beside the dream's."""
        steps = sum(self.real_steps_played)
        return {**self._asdict(), "real_return": float(np.mean(self.real_returns)),
                "real_per_dream": float(np.sum(self.real_returns) / max(steps, 1) * dream_length)}


class DreamRun(NamedTuple):
    """What :func:`learn_in_dream` returns: the VAE, the kept controller's memory and flat
    parameters (D,), the iteration it came from, every iteration's record, and the budget."""
    vae: object
    memory: object
    params: np.ndarray
    kept: int
    iterations: list
    budget: Budget


def play_bouts(params: np.ndarray, vision, memory, seeds, budget: Budget, stage: str, store: Path,
               noop_max: int) -> tuple[list, list]:
    """The controller ``params`` (D,) plays one real bout per seed, each capped so that all fit in
    what the budget has left; the bouts join ``store`` and are charged to ``stage``. Returns their
    returns and steps (empty where nothing is left)."""
    cap = budget.remaining // len(seeds)
    if cap < 1:
        return [], []
    game = make_game(GAME, len(seeds), noop_max=noop_max)
    frames, moves = [], []
    try:
        returns, steps = evaluate_population(params[None], game, vision, memory, seeds=np.asarray(seeds), max_steps=cap,
                                             frames=frames, moves=moves)
    finally:
        game.close()
    budget.charge(stage, int(steps.sum()))
    ended = len(moves) < cap  # every bout ended in the game, none cut by the cap
    with EpisodeStore(store, "a") as episodes:
        for n, length in enumerate(steps[0]):
            terminals = np.zeros(length, bool)
            terminals[-1] = length < len(moves) or ended
            episodes.append_episode(np.stack([f[n] for f in frames[:length]]),
                                    np.array([m[0][n] for m in moves[:length]], np.int64),
                                    np.array([m[1][n] for m in moves[:length]], np.float32), terminals)
    return returns[0].tolist(), steps[0].tolist()


@torch.inference_mode()
def dream_starts(memory, latents: LatentStore, n: int, warmup: int, rng: np.random.Generator):
    """``n`` real states to dream from: stretches of ``warmup + 1`` stored steps, the memory
    warmed on the first ``warmup``. Returns the next latents (n, L) and the LSTM state there."""
    chunk = latents.sample_chunks(n, warmup + 1, rng)
    out = memory(chunk["mu"][:, :warmup], chunk["actions"][:, :warmup])
    return chunk["mu"][:, warmup], out.state


def learn_in_dream(work: Path, cfg: DreamConfig, vision_cfg: VisionConfig, memory_cfg: MemoryConfig, *,
                   progress: bool = True, on_iteration=None) -> DreamRun:
    """The procedure of the module docstring in the folder ``work``, emptied first (a run cut off
    starts again; a lock file stays); ``on_iteration(record)`` is called after each iteration
    (with ``progress``, a line is printed)."""
    work.mkdir(parents=True, exist_ok=True)
    for stale in (path for path in work.iterdir() if path.name != LOCK_NAME):
        shutil.rmtree(stale) if stale.is_dir() else stale.unlink()
    budget, seed = Budget(cfg.budget), cfg.seed
    store = work / "real.h5"
    collect(GAME, cfg.random_bouts, store, workers=1, seed=seed, preprocessing="world_models",
            max_steps=budget.total // (2 * cfg.random_bouts), progress=progress)  # half the budget at most
    with EpisodeStore(store) as episodes:
        budget.charge("random play", episodes.num_steps)
    vae, _ = train_vision(store, work, vision_cfg, seed=seed, progress=progress)
    vision = VAEVision(vae)
    latents = encode_store(store, vae, work / "latents-0.h5", progress=progress)
    memory, _ = train_memory(latents, work / "memory-0", memory_cfg, N_ACTIONS, seed=seed, progress=progress,
                             reward_weight=cfg.reward_weight)
    tuning = dataclasses.replace(memory_cfg, steps=cfg.memory_updates, eval_every=max(1, min(100, cfg.memory_updates)))
    D = num_parameters(vae.latent_size + memory.hidden_size, N_ACTIONS)
    es = new_strategy(D, SimpleNamespace(population=cfg.population, seed=seed, sigma=cfg.sigma, diagonal=True))
    iterations, best = [], (-np.inf, None, None, -1)
    for i in range(10**6):
        if budget.remaining // cfg.bouts < 1:
            break
        started = time.perf_counter()
        dream_return = evolve(es, memory, LatentStore(latents), cfg, i)
        mean = np.asarray(es.mean, np.float64)
        seeds = (derive_seeds(seed, 2, i, n=cfg.bouts) >> 1).astype(np.int64)
        returns, steps = play_bouts(mean, vision, memory, seeds, budget, "controller's bouts", store, cfg.noop_max)
        if not returns:
            break
        record = Iteration(i, budget.used, dream_return, returns, steps, time.perf_counter() - started)
        iterations.append(record.record(cfg.dream_length))
        if np.mean(returns) > best[0]:
            best = (float(np.mean(returns)), mean.copy(), copy.deepcopy(memory), i)
        if progress:
            print(f"iteration {i}: {budget.used:,} real steps, dream {dream_return:+.2f}, real {np.mean(returns):+.1f}",
                  flush=True)
        if on_iteration is not None:
            on_iteration(iterations[-1])
        if budget.remaining // cfg.bouts < 1:
            break
        latents = encode_store(store, vae, work / f"latents-{i + 1}.h5", progress=False)
        (work / f"latents-{i}.h5").unlink(missing_ok=True)
        memory, _ = train_memory(latents, work / f"memory-{i + 1}", tuning, N_ACTIONS, seed=seed + i + 1,
                                 progress=False, initial=memory, reward_weight=cfg.reward_weight)
    if best[1] is None:
        raise BudgetExceeded(f"a budget of {cfg.budget:,} real agent steps leaves no bout for the controller after "
                             f"{cfg.random_bouts} random bouts")
    return DreamRun(vae, best[2], best[1], best[3], iterations, budget)


def evolve(es, memory, latents: LatentStore, cfg: DreamConfig, iteration: int) -> float:
    """``cfg.generations`` CMA-ES generations of ``es`` (in place) inside ``memory``'s dream (module
    docstring, 3a); returns the new mean's dream return over fresh starts."""
    for g in range(cfg.generations):
        rng = np.random.default_rng([cfg.seed, iteration, g])
        z, state = dream_starts(memory, latents, cfg.starts, cfg.warmup, rng)
        candidates = np.array(es.ask())
        generator = torch.Generator().manual_seed(int(rng.integers(2**31)))
        returns, _ = dream_population(candidates, memory, z, start_state=state, temperature=cfg.temperature,
                                      max_steps=cfg.dream_length, generator=generator)
        es.tell(list(candidates), (-returns.mean(axis=1)).tolist())
    rng = np.random.default_rng([cfg.seed, iteration, 10**6])
    z, state = dream_starts(memory, latents, 4 * cfg.starts, cfg.warmup, rng)
    returns, _ = dream_population(np.asarray(es.mean)[None], memory, z, start_state=state, temperature=cfg.temperature,
                                  max_steps=cfg.dream_length, generator=torch.Generator().manual_seed(iteration))
    return float(returns.mean())


def controller_run(run: DreamRun, cfg: DreamConfig) -> ControllerRun:
    """The kept controller as a :class:`~wmthesis.world_models.evolution.ControllerRun`, the form
    a World Models agent file is written from."""
    from wmthesis.utils import fingerprint

    task = dict(env=GAME, env_options={}, latent_size=run.vae.latent_size, hidden_size=run.memory.hidden_size,
                n_actions=N_ACTIONS, memory=fingerprint(run.memory), vision=fingerprint(run.vae), vision_bfloat16=False)
    config = {**dataclasses.asdict(cfg), "max_steps": None}  # a World Models agent plays whole bouts
    return ControllerRun(config, task, run.kept + 1, None, [], run.params, -np.inf, run.params)


__all__ = ["Budget", "BudgetExceeded", "DreamRun", "Iteration", "learn_in_dream", "play_bouts", "dream_starts", "evolve",
           "controller_run"]
