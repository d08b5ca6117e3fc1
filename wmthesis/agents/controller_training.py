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
(:class:`VAEVision` wraps the VAE: ``z = mu``, no sampling). Memory may be ``None`` (controller
on ``z`` alone).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import pickle
import time
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.core import Callback, Mind
from wmthesis.models.controller import Controller, features, num_parameters, population_scores, unflatten
from wmthesis.models.memory import Mixture, sample_mixture
from wmthesis.models.vae import frames_to_input
from wmthesis.training import check_resumable
from wmthesis.utils import atomic_path, check_choice, derive_seeds, read_pickle

FORMAT = "wmthesis-controller"
FORMAT_VERSION = 1
CHECKPOINT_NAME = "controller.pkl"
CURVE_NAME = "curve.json"
RESUMABLE_FIELDS = ("generations",)  # config fields that may change when resuming


# ----------------------------------------------------------------------------- vision
class VAEVision:
    """The VAE's encoder as vision: uint8 frames (N, 64, 64, 3) -> latent means ``mu`` (N, L).

    ``bfloat16=True`` encodes under bfloat16 autocast: about twice as fast on a CPU with
    AVX-512 BF16, latents within ~1e-2 of float32 (use the same vision to train and to play).
    """

    def __init__(self, vae: torch.nn.Module, bfloat16: bool = False):
        self.vae, self.bfloat16 = vae.eval(), bfloat16
        self.latent_size = vae.latent_size

    def __call__(self, frames: torch.Tensor) -> torch.Tensor:
        device = next(self.vae.parameters()).device
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=self.bfloat16):
            return self.vae.encode(frames_to_input(frames.to(device)))[0].float()


# ----------------------------------------------------------------------------- games
@contextmanager
def _timed(timings: dict | None, key: str):
    start = time.perf_counter()
    yield
    if timings is not None:
        timings[key] += time.perf_counter() - start


class AtariGame:
    """``num_envs`` Atari games in ale-py's C++ vector env with World Models frames.

    Same dynamics as :func:`wmthesis.envs.atari.make_atari` (frame skip 4, sticky actions off,
    no max-pooling, no fire on reset, unclipped rewards), raw frames cropped and resized to
    (64, 64, 3) uint8 here with the same :func:`crop_resize`. The games are deterministic, so
    ``reset(seeds)`` only draws, from each episode's seed, its number of leading no-op actions
    in ``[0, noop_max)`` (``noops``, (N,)), which the evaluator plays before the controller
    takes over (a seeded reset of ale-py reloads the ROM: ~0.15 s an env). ``step(actions)``
    returns ``(frames, rewards, done)``; once an env's episode ended, its rewards are 0 and its
    frames stale. ``timings`` accumulates seconds under ``env`` and ``preprocess``.
    """

    def __init__(self, game: str, num_envs: int, *, noop_max: int = 30, action_repeat: int = 4,
                 num_threads: int | None = None):
        from ale_py.vector_env import AtariVectorEnv

        from wmthesis.envs.preprocessing import CROPS

        self.num_envs, self.crop = num_envs, CROPS[game]
        self.env = AtariVectorEnv(
            game.lower(), num_envs, num_threads=num_threads or min(num_envs, os.cpu_count() or 1),
            img_height=210, img_width=160, grayscale=False, stack_num=1, frameskip=action_repeat,
            maxpool=False, repeat_action_probability=0.0, noop_max=0, reward_clipping=False,
            episodic_life=False, use_fire_reset=False)
        self.n_actions, self.noop_max = int(self.env.single_action_space.n), noop_max
        self.noops = np.zeros(num_envs, np.int64)
        self.frames = np.zeros((num_envs, 64, 64, 3), np.uint8)
        self.done = np.ones(num_envs, bool)
        self.timings: dict = defaultdict(float)

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        with _timed(self.timings, "env"):
            raw, _ = self.env.reset()
        self.noops = np.array([np.random.default_rng(int(s)).integers(max(self.noop_max, 1)) for s in seeds])
        self.done[:] = False
        return self._preprocess(raw)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        with _timed(self.timings, "env"):
            raw, rewards, terminated, truncated, _ = self.env.step(np.asarray(actions, np.int64))
        rewards = np.where(self.done, 0.0, rewards.astype(np.float64))
        self.done |= terminated | truncated
        return self._preprocess(raw), rewards, self.done.copy()

    def _preprocess(self, raw: np.ndarray) -> np.ndarray:
        """(N, 1, 210, 160, 3) raw frames -> (N, 64, 64, 3) World Models frames (live envs only)."""
        from wmthesis.envs.preprocessing import crop_resize

        with _timed(self.timings, "preprocess"):
            for i in np.flatnonzero(~self.done):
                self.frames[i] = crop_resize(raw[i, 0], self.crop, 64)
        return self.frames

    def close(self) -> None:
        self.env.close()


class ListGame:
    """``num_envs`` gymnasium envs from ``make()`` stepped in a list (Sokoban); same interface
    as :class:`AtariGame`. Observations are as the envs return them; ``reset(seeds)`` seeds
    each env's episode (a new Sokoban level per seed); no leading no-ops."""

    def __init__(self, make: Callable, num_envs: int):
        self.envs = [make() for _ in range(num_envs)]
        self.num_envs, self.n_actions = num_envs, int(self.envs[0].action_space.n)
        self.noops = np.zeros(num_envs, np.int64)  # Sokoban has no no-op action
        self.observations: np.ndarray | None = None
        self.done = np.ones(num_envs, bool)
        self.timings: dict = defaultdict(float)

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        with _timed(self.timings, "env"):
            self.observations = np.stack([env.reset(seed=int(s))[0] for env, s in zip(self.envs, seeds)])
        self.done[:] = False
        return self.observations

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rewards = np.zeros(self.num_envs)
        with _timed(self.timings, "env"):
            for i in np.flatnonzero(~self.done):
                observation, rewards[i], terminated, truncated, _ = self.envs[i].step(int(actions[i]))
                self.observations[i] = observation
                self.done[i] = terminated or truncated
        return self.observations, rewards, self.done.copy()

    def close(self) -> None:
        for env in self.envs:
            env.close()


def make_game(name: str, num_envs: int, *, noop_max: int = 30, num_threads: int | None = None, **options):
    """``num_envs`` copies of game ``name`` for batched evaluation.

    Atari games (``boxing``, ``freeway``): :class:`AtariGame` (options: ``action_repeat``).
    Sokoban: :class:`ListGame` of ``make_env(name, **options)`` (``noop_max`` is unused).
    """
    from wmthesis.envs import ATARI_GAMES, make_env

    check_choice("environment", name, tuple(ATARI_GAMES) + ("sokoban", "sokoban-small"))
    if name in ATARI_GAMES:
        unknown = sorted(set(options) - {"action_repeat"})
        if unknown:
            raise TypeError(f"unknown option(s) {unknown} for the batched {name!r}; valid: action_repeat")
        return AtariGame(ATARI_GAMES[name], num_envs, noop_max=noop_max, num_threads=num_threads, **options)
    return ListGame(lambda: make_env(name, **options), num_envs)


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
                        timings: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Play every candidate on the same E seeded episodes in the real game, all at once.

    ``params``: (P, D) flat controllers; ``game``: N = P * E envs (:func:`make_game`), env
    ``p * E + e`` plays candidate p's episode e; ``seeds``: (E,). Each step: vision encodes all
    N frames to z (N, L), each candidate scores its own episodes, argmax (a no-op instead
    during an episode's leading ``game.noops``), the memory steps on ``(z, a)`` to give the
    next h (N, H), the game steps. Stops when every episode ended or after ``max_steps``
    steps. Returns returns and steps, each (P, E). ``timings`` (a dict of floats) accumulates
    seconds under ``vision``, ``memory`` and ``controller``.
    """
    P, E = len(params), len(seeds)
    if game.num_envs != P * E:
        raise ValueError(f"the game has {game.num_envs} envs; {P} candidates x {E} episodes need {P * E}")
    frames = game.reset(np.tile(np.asarray(seeds), P))
    with _timed(timings, "vision"):
        z = vision(torch.from_numpy(frames))
    H = 0 if memory is None else memory.hidden_size
    weight, bias = _population(params, z.shape[-1] + H, game.n_actions, z.device)
    state = None if memory is None else memory.initial_state(P * E, z.device)
    h = torch.zeros(P * E, H, device=z.device)
    returns, steps = np.zeros(P * E), np.zeros(P * E, np.int64)
    noops = torch.as_tensor(game.noops, device=z.device)
    for t in range(max_steps or 2**62):
        with _timed(timings, "controller"):
            actions = torch.where(noops > t, 0, _act(weight, bias, z, h))
        if memory is not None:
            with _timed(timings, "memory"):
                out = memory.step(z, actions, state)
                h, state = out.hidden, out.state
        alive = ~game.done
        frames, rewards, done = game.step(actions.cpu().numpy())
        returns += rewards
        steps += alive
        if done.all():
            break
        with _timed(timings, "vision"):
            z = vision(torch.from_numpy(frames))
    return returns.reshape(P, E), steps.reshape(P, E)


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
                     timings: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Play every candidate on E dreamed episodes, all at once, with the memory as environment.

    ``params``: (P, D); ``start_latents``: (E, L), the encoded first frames of E real episodes;
    ``noops``: (E,) leading no-op actions, as in the real game. Each step: the controller acts
    on ``[z h]``; the memory reads ``(z, a)`` and predicts the reward, done (``P(done) > 0.5``)
    and the next latent, sampled at ``temperature``. Returns returns and steps, each (P, E).
    """
    P, E = len(params), len(start_latents)
    z = start_latents.repeat(P, 1)  # (P * E, L): row p * E + e
    weight, bias = _population(params, z.shape[-1] + memory.hidden_size, memory.n_actions, z.device)
    state = memory.initial_state(P * E, z.device)
    h = torch.zeros(P * E, memory.hidden_size, device=z.device)
    noops = torch.as_tensor(np.zeros(E) if noops is None else noops, device=z.device).repeat(P)
    alive = torch.ones(P * E, dtype=torch.bool, device=z.device)
    returns = torch.zeros(P * E, dtype=torch.float64, device=z.device)
    steps = torch.zeros(P * E, dtype=torch.int64, device=z.device)
    for t in range(max_steps):
        with _timed(timings, "controller"):
            actions = torch.where(noops > t, 0, _act(weight, bias, z, h))
        with _timed(timings, "memory"):
            out = memory.step(z, actions, state)
            returns += out.reward.double() * alive
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
    """A ``cma.CMAEvolutionStrategy`` from zero with step size ``cfg.sigma``, quiet, no files."""
    import cma

    options = {"popsize": cfg.population, "seed": np.nan, "randn": SeededNormal(cfg.seed),
               "verbose": -9, "verb_disp": 0, "verb_log": 0, "maxiter": np.inf, "CMA_diagonal": cfg.diagonal}
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

    ``vision``: frames -> z (e.g. :class:`VAEVision`); ``memory``: a
    :class:`~wmthesis.models.memory.Memory` or None; ``cfg``: a
    :class:`~wmthesis.config.ControllerConfig`. With ``out_dir``, each generation writes
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
                memory=_fingerprint(memory), vision=_fingerprint(getattr(vision, "vae", vision)),
                vision_bfloat16=bool(getattr(vision, "bfloat16", False)))


def _fingerprint(model) -> str | None:
    """A hash of a module's weights (None for anything else, e.g. a plain function)."""
    if not isinstance(model, torch.nn.Module):
        return None
    digest = hashlib.sha1()
    for name, tensor in model.state_dict().items():
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


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
    with atomic_path(out_dir / CURVE_NAME) as tmp:
        tmp.write_text(json.dumps({"config": run.config, "task": run.task, "curve": run.curve}, indent=1))


def load_run(path: str | os.PathLike) -> ControllerRun:
    """A :class:`ControllerRun` from ``controller.pkl`` (or the folder holding it)."""
    path = Path(path)
    path = path / CHECKPOINT_NAME if path.is_dir() else path
    saved = read_pickle(path)
    stamp = (saved.pop("format", None), saved.pop("version", None)) if isinstance(saved, dict) else None
    if stamp != (FORMAT, FORMAT_VERSION):
        raise ValueError(f"{path} is not a {FORMAT} checkpoint of version {FORMAT_VERSION}")
    return ControllerRun(**saved)


# ----------------------------------------------------------------------------- figures
def plot_learning_curve(curve: list[dict], ax=None, title: str | None = None):
    """Best/mean/worst population fitness per generation (the band spans worst to best) and,
    where present, the real-game return of the CMA-ES mean (mean +- std). Returns the figure."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6, 3.5))
    generation = [e["generation"] for e in curve]
    ax.fill_between(generation, [e["worst"] for e in curve], [e["best"] for e in curve], alpha=0.2,
                    label="population (worst to best)")
    ax.plot(generation, [e["best"] for e in curve], lw=1, label="best")
    ax.plot(generation, [e["mean"] for e in curve], lw=1.5, label="mean")
    evals = [e for e in curve if "eval_return" in e]
    if evals:
        ax.errorbar([e["generation"] for e in evals], [e["eval_return"] for e in evals],
                    [e["eval_std"] for e in evals], fmt="o", ms=3, capsize=2, color="k",
                    label="CMA-ES mean, real game")
    ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel("return")
    ax.set_title(title or "Controller fitness (CMA-ES)")
    ax.legend(fontsize=7)
    ax.figure.tight_layout()
    return ax.figure


# ----------------------------------------------------------------------------- the mind
class ControllerMind(Mind, Callback):
    """Vision + memory + controller as a HumbleRL mind, for :func:`wmthesis.core.loop`.

    It is also a callback that advances the memory with the action actually taken and resets
    it at each episode start, so pass it both ways::

        loop(env, mind, callbacks=[mind], policy="deterministic")

    ``plan(state)``: the observation (e.g. (64, 64, 3) uint8) -> action scores (A,).
    """

    def __init__(self, vision: Callable, memory, controller: Controller):
        self.vision, self.memory, self.controller = vision, memory, controller
        if memory is not None:
            memory.eval()
        self.reset()

    def reset(self) -> None:
        self.state = None if self.memory is None else self.memory.initial_state(1)
        self.h = None if self.memory is None else torch.zeros(1, self.memory.hidden_size)
        self.z = None

    @torch.inference_mode()
    def plan(self, state, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        if self.z is not None:
            raise RuntimeError("ControllerMind.plan was called twice without a step: pass the mind "
                               "as a callback too, loop(env, mind, callbacks=[mind])")
        self.z = self.vision(torch.as_tensor(np.asarray(state))[None])
        h = None if self.h is None else self.h.to(self.z.device)
        return self.controller.to(self.z.device)(self.z, h)[0].cpu().numpy()

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.reset()

    @torch.inference_mode()
    def on_step_taken(self, step, transition, info) -> None:
        if self.memory is not None:
            action = torch.tensor([transition.action], device=self.z.device)
            out = self.memory.step(self.z, action, self.state)
            self.h, self.state = out.hidden, out.state
        self.z = None
