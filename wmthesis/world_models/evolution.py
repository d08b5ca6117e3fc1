"""Controller training with CMA-ES (thesis 4.2.2, 4.2.5), in the real game or inside the dream.

A generation, top to bottom (:func:`train_controller`):

1. CMA-ES (the ``cma`` package) proposes ``population`` flat controller vectors (P, D).
2. Every candidate plays the same ``episodes`` starts (E seeded episodes shared by the whole
   population, so candidates are ranked on equal terms). All P x E games step at once: one
   vector env step, one batched vision encode and one batched memory step per time step
   (:func:`evaluate_population`). In the dream (``dream=True``, beyond the thesis, after Ha &
   Schmidhuber's VizDoom experiment) the memory is the environment: it samples the next latent
   with temperature tau and predicts reward and done (:func:`dream_population`).
3. Fitness = mean return over the E episodes; CMA-ES minimises, so it is told ``-fitness``.
4. The best/mean/worst fitness go to the learning curve; every ``eval_every`` generations the
   CMA-ES mean plays ``eval_episodes`` real episodes (the only real-game score of a dream run).
5. A checkpoint (the pickled ``CMAEvolutionStrategy``, best and mean weights, curve, config) is
   written atomically, so a killed run resumes where it stopped and reaches the same result.

Episode starts: Boxing with sticky actions off is deterministic, so each episode begins with a
random number of no-op actions in ``[0, noop_max)`` (the controller is overridden, the memory
still reads them), seeded per episode from ``(seed, generation)``; Sokoban draws a new level
from the same seeds instead.

Vision is any callable ``frames -> z``: uint8 (N, *observation_shape) tensor -> float (N, L)
(:class:`~wmthesis.world_models.vision.VAEVision` wraps the VAE: ``z = mu``, no sampling).
Memory may be ``None`` (controller on ``z`` alone).
"""
from __future__ import annotations

import dataclasses
import os
import pickle
import time
from pathlib import Path
from typing import Callable

import cma
import numpy as np
import torch
from tqdm import tqdm

from wmthesis.envs.vector import make_game
from wmthesis.runs import atomic_path, write_json
from wmthesis.training import check_resumable
from wmthesis.utils import check_choice, derive_seeds, fingerprint, read_pickle, timed
from wmthesis.world_models.controller import Controller, features, num_parameters, population_scores, unflatten
from wmthesis.world_models.memory import Mixture, sample_mixture

FORMAT = "wmthesis-controller"
FORMAT_VERSION = 1
CHECKPOINT_NAME = "controller.pkl"
CURVE_NAME = "curve.json"
RESUMABLE_FIELDS = ("generations",)  # config fields that may change when resuming


# ----------------------------------------------------------------------------- evaluation
def _act(weight: torch.Tensor, bias: torch.Tensor, z: torch.Tensor, h: torch.Tensor | None) -> torch.Tensor:
    """Greedy actions of P candidates on their E episodes: z (P*E, L), h (P*E, H) -> (P*E,)."""
    P = weight.shape[0]
    x = features(z, h).reshape(P, -1, weight.shape[-1])
    return population_scores(weight, bias, x).argmax(-1).reshape(-1)


def _population(params, in_features: int, n_actions: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    params = torch.as_tensor(np.asarray(params), dtype=torch.float32, device=device)
    return unflatten(params, in_features, n_actions)


@torch.inference_mode()
def evaluate_population(params, game, vision: Callable, memory=None, *, seeds, max_steps: int | None = None,
                        timings: dict | None = None, frames: list | None = None,
                        moves: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Play every candidate on the same E seeded episodes in the real game, all at once.

    ``params``: (P, D) flat controllers; ``game``: N = P * E envs (:func:`make_game`), env
    ``p * E + e`` plays candidate p's episode e; ``seeds``: (E,). Each step: vision encodes all
    N frames to z (N, L), each candidate scores its own episodes, argmax (a no-op instead
    during an episode's leading ``game.noops``), the memory steps on ``(z, a)`` to give the
    next h (N, H), the game steps. Stops when every episode ended or after ``max_steps``
    steps. Returns returns and steps, each (P, E). ``timings`` (a dict of floats) accumulates
    seconds under ``vision``, ``memory`` and ``controller``; ``frames`` (a list) gets every
    step's frames, (N, 64, 64, 3) uint8 each, the first the starts' (env n's episode ends at
    its ``steps``); ``moves`` (a list) gets every step's actions and rewards, (N,) each, as pairs.
    """
    P, E = len(params), len(seeds)
    if game.num_envs != P * E:
        raise ValueError(f"the game has {game.num_envs} envs; {P} candidates x {E} episodes need {P * E}")
    shown = game.reset(np.tile(np.asarray(seeds), P))
    if frames is not None:
        frames.append(shown.copy())
    with timed(timings, "vision"):
        z = vision(torch.from_numpy(shown))
    H = 0 if memory is None else memory.hidden_size
    weight, bias = _population(params, z.shape[-1] + H, game.n_actions, z.device)
    state = None if memory is None else memory.initial_state(P * E, z.device)
    h = torch.zeros(P * E, H, device=z.device)
    returns, steps = np.zeros(P * E), np.zeros(P * E, np.int64)
    noops = torch.as_tensor(game.noops, device=z.device)
    for t in range(max_steps or 2**62):
        with timed(timings, "controller"):
            actions = torch.where(noops > t, 0, _act(weight, bias, z, h))
        if memory is not None:
            with timed(timings, "memory"):
                out = memory.step(z, actions, state)
                h, state = out.hidden, out.state
        alive = ~game.done
        shown, rewards, done = game.step(actions.cpu().numpy())
        if frames is not None:
            frames.append(shown.copy())
        if moves is not None:
            moves.append((actions.cpu().numpy(), np.asarray(rewards, np.float32) * alive))
        returns += rewards
        steps += alive
        if done.all():
            break
        with timed(timings, "vision"):
            z = vision(torch.from_numpy(shown))
    return returns.reshape(P, E), steps.reshape(P, E)


FINAL_SEEDS = 1_000_000  # the first seed of the bouts a finished controller is scored on


def final_bout_seeds(n: int) -> np.ndarray:
    """The seeds of the ``n`` bouts a finished controller is scored on (the same for every
    controller and seed, apart from every generation's): (n,)."""
    return np.arange(n) + FINAL_SEEDS


def score_bouts(params, vision: Callable, memory, bouts: int, noop_max: int, max_steps: int | None = None) -> np.ndarray:
    """A finished controller ``params`` (D,) over the first ``bouts`` bouts every controller is
    scored on (:func:`final_bout_seeds`; full bouts unless ``max_steps``): its returns, (bouts,)."""
    game = make_game("boxing", bouts, noop_max=noop_max)
    try:
        returns, _ = evaluate_population(np.asarray(params)[None], game, vision, memory, seeds=final_bout_seeds(bouts),
                                         max_steps=max_steps)
    finally:
        game.close()
    return returns[0]


def random_play(game, seeds, *, seed: int = 0, max_steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Uniformly random actions on the E seeded episodes ``seeds`` of ``game`` (E envs, from
    :func:`make_game`): the baseline a controller is scored against on the same starts (the
    same Sokoban levels). Actions come from ``numpy.random.default_rng(seed)``. Returns returns
    and steps, each (E,)."""
    if game.num_envs != len(seeds):
        raise ValueError(f"the game has {game.num_envs} envs for {len(seeds)} episodes")
    rng = np.random.default_rng(seed)
    game.reset(np.asarray(seeds))
    returns, steps = np.zeros(game.num_envs), np.zeros(game.num_envs, np.int64)
    for _ in range(max_steps or 2**62):
        alive = ~game.done
        _, rewards, done = game.step(rng.integers(game.n_actions, size=game.num_envs))
        returns += rewards
        steps += alive
        if done.all():
            break
    return returns, steps


def next_latent(prediction: Mixture | torch.Tensor, temperature: float, generator=None) -> torch.Tensor:
    """The dream's next latent: a sample of the mixture at temperature tau, or the deterministic
    memory's prediction as is. (B, K, L) mixture or (B, L) -> (B, L)."""
    if isinstance(prediction, Mixture):
        return sample_mixture(prediction, temperature, generator)
    return prediction


@torch.inference_mode()
def dream_population(params, memory, start_latents: torch.Tensor, *, temperature: float = 1.0,
                     max_steps: int = 1000, noops=None, generator: torch.Generator | None = None,
                     timings: dict | None = None, start_state: tuple | None = None,
                     penalty=None) -> tuple[np.ndarray, np.ndarray]:
    """Play every candidate on E dreamed episodes, all at once, with the memory as environment.

    ``params``: (P, D); ``start_latents``: (E, L), the encoded first frames of E real episodes,
    or real states met later in them, with the memory's LSTM state there (``start_state``, each
    (1, E, H); None: an episode's start); ``noops``: (E,) leading no-op actions, as in the real
    game. Each step: the controller acts on ``[z h]``; the memory reads ``(z, a)`` and predicts
    the reward, done (``P(done) > 0.5``) and the next latent, sampled at ``temperature``;
    ``penalty`` (where given), a function of ``(z, actions)`` (N, L), (N,) -> (N,), is taken off
    each step's reward. Returns returns and steps, each (P, E).
    """
    P, E = len(params), len(start_latents)
    z = start_latents.repeat(P, 1)  # (P * E, L): row p * E + e
    weight, bias = _population(params, z.shape[-1] + memory.hidden_size, memory.n_actions, z.device)
    if start_state is None:
        state = memory.initial_state(P * E, z.device)
        h = torch.zeros(P * E, memory.hidden_size, device=z.device)
    else:
        state = tuple(part.repeat(1, P, 1) for part in start_state)
        h = state[0][0]
    noops = torch.as_tensor(np.zeros(E) if noops is None else noops, device=z.device).repeat(P)
    alive = torch.ones(P * E, dtype=torch.bool, device=z.device)
    returns = torch.zeros(P * E, dtype=torch.float64, device=z.device)
    steps = torch.zeros(P * E, dtype=torch.int64, device=z.device)
    for t in range(max_steps):
        with timed(timings, "controller"):
            actions = torch.where(noops > t, 0, _act(weight, bias, z, h))
        with timed(timings, "memory"):
            out = memory.step(z, actions, state)
            reward = out.reward if penalty is None else out.reward - penalty(z, actions)
            returns += reward.double() * alive
            steps += alive
            alive &= out.done_logit <= 0
            if not alive.any():
                break
            z, h, state = next_latent(out.next_latent, temperature, generator), out.hidden, out.state
    return returns.cpu().numpy().reshape(P, E), steps.cpu().numpy().reshape(P, E)


# ----------------------------------------------------------------------------- CMA-ES
class SeededNormal:
    """CMA-ES's ``randn`` option: standard normals from a generator reseeded each generation,
    so a resumed run draws exactly what an uninterrupted one would (and NumPy's global RNG is
    never touched). Picklable with the ``CMAEvolutionStrategy``."""

    def __init__(self, seed=0):
        self.rng = np.random.default_rng(seed)

    def __call__(self, *shape) -> np.ndarray:
        return self.rng.standard_normal(shape)


def new_strategy(dimension: int, cfg):
    """A ``cma.CMAEvolutionStrategy`` from zero with step size ``cfg.sigma``, quiet, no files;
    separable (``cfg.diagonal``) and mirrored (``cfg.mirrored``) where the config says."""
    options = {"popsize": cfg.population, "seed": np.nan, "randn": SeededNormal(cfg.seed),
               "verbose": -9, "verb_disp": 0, "verb_log": 0, "maxiter": np.inf, "CMA_diagonal": cfg.diagonal,
               **({"CMA_mirrors": cfg.population // 2, "CMA_mirrormethod": 0} if getattr(cfg, "mirrored", False)
                  else {})}
    return cma.CMAEvolutionStrategy(np.zeros(dimension), cfg.sigma, options)


def episode_seeds(seed: int, generation: int, n: int, stream: int = 0) -> np.ndarray:
    """``n`` episode seeds (non-negative 31-bit ints) for ``generation``; ``stream`` 0 trains,
    1 evaluates."""
    return (derive_seeds(seed, stream, generation, n=n) >> 1).astype(np.int64)


@dataclasses.dataclass
class ControllerRun:
    """What :func:`train_controller` returns (and its checkpoint holds).

    ``curve``: one dict per generation (``generation``, ``best``, ``mean``, ``worst`` fitness,
    ``sigma``, ``agent_steps`` so far in the real game, ``seconds``, and ``eval_return`` /
    ``eval_std`` where the mean was played in the real game). ``task``: env name, options and
    the sizes L, H, A. ``best_params``: the best candidate ever (by its noisy fitness);
    ``mean_params``: the CMA-ES mean, the usual final controller.
    """

    config: dict
    task: dict
    generation: int
    es: object
    curve: list
    best_params: np.ndarray
    best_fitness: float
    mean_params: np.ndarray

    def controller(self, which: str = "mean") -> Controller:
        """The ``best`` or ``mean`` controller as a module."""
        check_choice("controller", which, ("best", "mean"))
        params = self.best_params if which == "best" else self.mean_params
        t = self.task
        return Controller.from_flat(params, t["latent_size"], t["hidden_size"], t["n_actions"])


def train_controller(env_name: str, vision: Callable, memory, cfg, *, out_dir: str | os.PathLike | None = None,
                     env_options: dict | None = None, num_threads: int | None = None,
                     torch_threads: int | None = None, progress: bool = True) -> ControllerRun:
    """Evolve a controller for ``env_name`` with CMA-ES (see the module docstring).

    ``vision``: frames -> z (e.g. :class:`~wmthesis.world_models.vision.VAEVision`); ``memory``: a
    :class:`~wmthesis.world_models.memory.Memory` or None; ``cfg``: a
    :class:`~wmthesis.world_models.config.ControllerConfig`. With ``out_dir``, each generation writes
    ``controller.pkl`` and ``curve.json`` there atomically, and an existing checkpoint is
    resumed: only ``generations`` may differ from its config, anything else (config, game,
    sizes, memory weights) raises :class:`~wmthesis.training.ConfigMismatch`.
    ``num_threads``: ale-py's stepping threads (default: one per core); ``torch_threads``: torch
    threads while training (default: as set). With more than one torch thread, start Python
    with ``OMP_WAIT_POLICY=PASSIVE``: otherwise torch's idle OpenMP threads spin and slow
    ale-py's stepping threads several-fold.
    """
    if cfg.dream and memory is None:
        raise ValueError("dream=True needs a memory: it is the environment of the dream")
    env_options = dict(env_options or {})
    if memory is not None:
        memory.eval()
    games = {}  # by size, made lazily: an AtariGame of 320 envs takes tens of seconds to start
    threads = torch.get_num_threads()
    torch.set_num_threads(torch_threads or threads)
    try:
        run = _start(cfg, out_dir, env_name, env_options, vision, memory, games, num_threads)
        with tqdm(total=cfg.generations, initial=run.generation, desc="CMA-ES", disable=not progress) as bar:
            while run.generation < cfg.generations:
                entry = _generation(run, cfg, env_name, env_options, vision, memory, games, num_threads)
                bar.update(1)
                bar.set_postfix(best=f"{entry['best']:.2f}", mean=f"{entry['mean']:.2f}")
                if out_dir is not None:
                    save_run(run, out_dir)
    finally:
        torch.set_num_threads(threads)
        for game in games.values():
            game.close()
    return run


def _start(cfg, out_dir, env_name, env_options, vision, memory, games, num_threads) -> ControllerRun:
    """A fresh run, or the checkpoint in ``out_dir`` after checking it matches."""
    probe = _game(games, cfg.eval_episodes if cfg.eval_every else cfg.episodes, env_name, cfg, env_options,
                  num_threads)
    task = _task(env_name, env_options, probe, vision, memory)
    checkpoint = None if out_dir is None else Path(out_dir) / CHECKPOINT_NAME
    if checkpoint is not None and checkpoint.exists():
        run = _resume(checkpoint, cfg, task)
        run.config = dataclasses.asdict(cfg)  # `generations` may have changed
        return run
    D = num_parameters(task["latent_size"] + task["hidden_size"], task["n_actions"])
    return ControllerRun(dataclasses.asdict(cfg), task, 0, new_strategy(D, cfg), [], np.zeros(D), -np.inf,
                         np.zeros(D))


def _generation(run: ControllerRun, cfg, env_name, env_options, vision, memory, games, num_threads) -> dict:
    """One CMA-ES generation on ``run`` (in place); returns its learning-curve entry."""
    start, g, E = time.perf_counter(), run.generation, cfg.episodes
    seeds = episode_seeds(cfg.seed, g, E)
    run.es.opts["randn"].rng = np.random.default_rng([cfg.seed, g])
    candidates = np.array(run.es.ask())
    agent_steps = run.curve[-1]["agent_steps"] if run.curve else 0
    if cfg.dream:
        starts = _game(games, E, env_name, cfg, env_options, num_threads)
        with torch.inference_mode():
            start_latents = vision(torch.from_numpy(starts.reset(seeds)))
        generator = torch.Generator(start_latents.device).manual_seed(int(seeds[0]))
        returns, _ = dream_population(candidates, memory, start_latents, temperature=cfg.temperature,
                                      max_steps=cfg.dream_max_steps, noops=starts.noops, generator=generator)
    else:
        game = _game(games, cfg.population * E, env_name, cfg, env_options, num_threads)
        returns, steps = evaluate_population(candidates, game, vision, memory, seeds=seeds,
                                             max_steps=cfg.max_steps)
        agent_steps += int(steps.sum())
    fitness = returns.mean(axis=1)
    run.es.tell(list(candidates), (-fitness).tolist())
    if fitness.max() > run.best_fitness:
        run.best_fitness, run.best_params = float(fitness.max()), candidates[fitness.argmax()].copy()
    run.mean_params = np.array(run.es.mean, dtype=np.float64)
    run.generation = g + 1
    entry = dict(generation=run.generation, best=float(fitness.max()), mean=float(fitness.mean()),
                 worst=float(fitness.min()), sigma=float(run.es.sigma))
    if cfg.eval_every and run.generation % cfg.eval_every == 0:
        eval_seeds = episode_seeds(cfg.seed, 0, cfg.eval_episodes, stream=1)
        game = _game(games, cfg.eval_episodes, env_name, cfg, env_options, num_threads)
        scores, steps = evaluate_population(run.mean_params[None], game, vision, memory, seeds=eval_seeds,
                                            max_steps=cfg.max_steps)
        entry.update(eval_return=float(scores.mean()), eval_std=float(scores.std()))
        agent_steps += int(steps.sum())
    entry.update(agent_steps=agent_steps, seconds=time.perf_counter() - start)
    run.curve.append(entry)
    return entry


def _game(games: dict, num_envs: int, env_name, cfg, env_options, num_threads):
    """The game of ``num_envs`` envs from ``games``, made on first use."""
    if num_envs not in games:
        games[num_envs] = make_game(env_name, num_envs, noop_max=cfg.noop_max, num_threads=num_threads,
                                    **env_options)
    return games[num_envs]


def _task(env_name: str, env_options: dict, probe, vision, memory) -> dict:
    """What a checkpoint must agree on besides the config: the game, the sizes, the models."""
    with torch.inference_mode():
        z = vision(torch.from_numpy(probe.reset(np.zeros(probe.num_envs, np.int64))))
    if memory is not None and memory.n_actions != probe.n_actions:
        raise ValueError(f"the memory was built for {memory.n_actions} actions; {env_name} has {probe.n_actions}")
    return dict(env=env_name, env_options=env_options, latent_size=int(z.shape[-1]),
                hidden_size=0 if memory is None else memory.hidden_size, n_actions=probe.n_actions,
                memory=fingerprint(memory), vision=fingerprint(getattr(vision, "vae", vision)),
                vision_bfloat16=bool(getattr(vision, "bfloat16", False)))


def _resume(path: Path, cfg, task: dict) -> ControllerRun:
    run = load_run(path)
    saved = {**dataclasses.asdict(type(cfg)()), **run.config}  # fields added since: their defaults
    check_resumable(path, (saved, run.task), (dataclasses.asdict(cfg), task), RESUMABLE_FIELDS)
    return run


def save_run(run: ControllerRun, out_dir: str | os.PathLike) -> None:
    """Write ``controller.pkl`` (everything, to resume) and ``curve.json`` atomically."""
    out_dir = Path(out_dir)
    with atomic_path(out_dir / CHECKPOINT_NAME) as tmp:
        with open(tmp, "wb") as f:
            pickle.dump({"format": FORMAT, "version": FORMAT_VERSION, **dataclasses.asdict(run)}, f)
    write_json(out_dir / CURVE_NAME, {"config": run.config, "task": run.task, "curve": run.curve})


def load_run(path: str | os.PathLike) -> ControllerRun:
    """A :class:`ControllerRun` from ``controller.pkl`` (or the folder holding it)."""
    path = Path(path)
    path = path / CHECKPOINT_NAME if path.is_dir() else path
    saved = read_pickle(path)
    stamp = (saved.pop("format", None), saved.pop("version", None)) if isinstance(saved, dict) else None
    if stamp != (FORMAT, FORMAT_VERSION):
        raise ValueError(f"{path} is not a {FORMAT} checkpoint of version {FORMAT_VERSION}")
    return ControllerRun(**saved)
