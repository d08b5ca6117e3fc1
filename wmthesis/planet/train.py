"""PlaNet's training pipeline (thesis 4.4.3, 5.5, 5.6): seed episodes, then train and plan.

1. Play ``seed_episodes`` random episodes (6) into the run's episode store.
2. Repeat until the store holds ``env_steps`` agent steps: ``update_steps`` (C) updates of the
   RSSM on batches of ``batch_size`` x ``chunk_length`` chunks (50 x 50), then one episode
   collected by the CEM planner with epsilon-greedy exploration (0.3); every
   ``test_interval`` collected episodes (and at the end), ``test_episodes`` greedy episodes.
3. After every collected episode a checkpoint (model, optimiser, random states, learning
   curve) is written atomically, so a run stopped anywhere resumes from its last episode;
   ``curve.json`` holds the learning curve (score against agent steps) in plain JSON.

Run folder: ``episodes.h5`` (:class:`~wmthesis.data.EpisodeStore` of 5-bit 64x64 frames),
``checkpoint.pt`` and ``curve.json``. :func:`train_planet` is the entry point;
:class:`PlanetMind` is the agent for :func:`wmthesis.core.loop`;
:func:`~wmthesis.planet.prediction.open_loop` and
:func:`~wmthesis.planet.figures.open_loop_figure` give the thesis's open-loop figures (Fig. 58, 59, 510, 511) and the
prediction error per horizon.

The thesis's experiments are config changes: :mod:`~wmthesis.planet.variants`.
"""
from __future__ import annotations

import dataclasses
import json
import math
import shutil
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.core import loop
from wmthesis.data import EpisodeStore
from wmthesis.envs import ATARI_GAMES
from wmthesis.planet.agent import PlanetMind, play_greedy
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.explore import build_disagreement, disagreement_loss, one_step_batch
from wmthesis.planet.frames import FRAME_SIZE, PlanetFrames, make_planet_env, planet_frame  # noqa: F401 (re-exported)
from wmthesis.planet.networks import build_model
from wmthesis.planet.rssm import RSSM, planet_loss
from wmthesis.planet.shipped import AGENT_NAME, load_agent
from wmthesis.planet.variants import variant_changes
from wmthesis.rollouts import EpisodeBuffer, episode_seeds, play_random_episode
from wmthesis.runs import atomic_path
from wmthesis.training import gradient_step, with_added_defaults
from wmthesis.utils import derive_seeds, device, seed_everything

CHECKPOINT, CURVE, STORE = "checkpoint.pt", "curve.json", "episodes.h5"
# Config fields that may change when a run resumes (a larger budget); any other must match.
RESUMABLE_CHANGES = ("env_steps",)

# ---------------------------------------------------------------------------- setup
def with_variant(config: PlaNetConfig, variant: str | dict | None) -> PlaNetConfig:
    """``config`` with a variant of :mod:`~wmthesis.planet.variants` (by name) or a dict of changes applied."""
    if variant is None:
        return config
    return dataclasses.replace(config, **(variant_changes(variant) if isinstance(variant, str) else variant))


def make_optimizer(model: RSSM, config: PlaNetConfig) -> torch.optim.Adam:
    return torch.optim.Adam(model.parameters(), lr=config.lr, eps=config.adam_eps)


# ---------------------------------------------------------------------------- training
class _RunState:
    """What a checkpoint holds besides the model and optimiser."""

    def __init__(self, seed: int, dev: torch.device):
        self.updates = 0
        self.explorer = self.explorer_optimizer = None  # the disagreement ensemble, when exploring
        self.np_rng = np.random.default_rng(seed)
        self.torch_rng = torch.Generator(dev).manual_seed(seed)
        self.curve: dict[str, list] = {"train": [], "test": []}
        self.seconds = 0.0


def train_planet(env_name: str, config: PlaNetConfig, run_dir, *, seed: int,
                 variant: str | dict | None = None, progress: bool = True, start_from=None) -> dict:
    """Train PlaNet on ``env_name`` until the store holds ``config.env_steps`` agent steps.

    ``start_from``: a run folder of the same environment, seed and config (another
    ``env_steps`` allowed) whose checkpoint and episodes a new ``run_dir`` starts from (copies;
    ignored once ``run_dir`` has a checkpoint): an agent that goes on from a model trained on
    seed episodes alone (``env_steps`` = 0).

    Resumes from ``run_dir`` when it holds a run of the same environment, seed and config
    (only :data:`RESUMABLE_CHANGES` may differ, e.g. a larger ``env_steps``); a finished run
    returns at once. A non-finite loss raises ``FloatingPointError`` naming the update and
    leaves the last good checkpoint in place. Returns a dict: ``run_dir``, ``env``,
    ``config`` (as a dict), ``episodes``, ``env_steps``, ``updates``, ``seconds``, ``curve``
    (``train`` and ``test`` lists) and ``final_test`` (the last test entry or None).
    """
    config = with_variant(config, variant)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if start_from is not None and not (run_dir / CHECKPOINT).exists():
        _copy_run(Path(start_from), run_dir)
    seed_everything(seed)
    dev = device()
    env = make_planet_env(env_name, config)
    model = build_model(config, env.action_space.n)
    optimizer = make_optimizer(model, config)
    run = _RunState(seed, dev)
    if config.explore_scale > 0:
        run.explorer = build_disagreement(model, config.hidden_size, config.explore_heads)
        run.explorer_optimizer = torch.optim.Adam(run.explorer.parameters(), lr=config.lr, eps=config.adam_eps)
    known = _load_checkpoint(run_dir / CHECKPOINT, model, optimizer, run, env_name, seed, config)
    store_options = dict(action_repeat=config.action_repeat, max_steps=config.max_episode_steps,
                         bits=config.bits, crop=config.crop)
    try:
        with EpisodeStore(run_dir / STORE, "a", env=env_name, preprocessing="planet", seed=seed,
                          obs_shape=(config.frame_size, config.frame_size, 3), env_options=store_options) as store:
            _seed_episodes(store, env, config, seed)
            _note_unknown_episodes(store, known, run, config)
            _pretrain(store, model, optimizer, run, config, env_name, seed, run_dir, progress)
            _train_loop(store, env, model, optimizer, run, config, env_name, seed, run_dir, progress)
            return _results(run_dir, env_name, config, store, run)
    finally:
        env.close()


def _pretrain(store, model, optimizer, run, config, env_name, seed, run_dir, progress):
    """Updates on the seed episodes alone until ``pretrain_updates``, a checkpoint after
    every ``update_steps`` (so a stopped run resumes from its last block)."""
    with tqdm(total=config.pretrain_updates, initial=min(run.updates, config.pretrain_updates), unit="update",
              desc=f"planet {env_name} on seed episodes", disable=not progress or config.pretrain_updates == 0) as bar:
        while run.updates < config.pretrain_updates:
            start = time.perf_counter()
            block = dataclasses.replace(config, update_steps=min(config.update_steps,
                                                                 config.pretrain_updates - run.updates))
            losses = train_updates(model, optimizer, store, block, run, run_dir)
            run.seconds += time.perf_counter() - start
            run.curve.setdefault("pretrain", []).append({"updates": run.updates, "seconds": run.seconds, **losses})
            _save_checkpoint(run_dir, model, optimizer, run, env_name, seed, config, len(store))
            bar.update(run.updates - bar.n)
            bar.set_postfix(loss=f"{losses['loss']:.1f}")


def _train_loop(store, env, model, optimizer, run, config, env_name, seed, run_dir, progress):
    bar = tqdm(total=config.env_steps, initial=min(store.num_steps, config.env_steps), unit="step",
               desc=f"planet {env_name}", disable=not progress)
    with bar:
        while store.num_steps < config.env_steps:
            start = time.perf_counter()
            losses = train_updates(model, optimizer, store, config, run, run_dir)
            entry = _collect_episode(store, env, model, config, seed, run.explorer)
            entry.update(updates=run.updates, **losses)
            run.curve["train"].append(entry)
            collected = len(store) - config.seed_episodes
            if collected % config.test_interval == 0 or store.num_steps >= config.env_steps:
                run.curve["test"].append(_test(env, model, config, seed, store, run))
            run.seconds += time.perf_counter() - start
            entry["seconds"] = run.seconds
            _save_checkpoint(run_dir, model, optimizer, run, env_name, seed, config, len(store))
            bar.update(min(store.num_steps, config.env_steps) - bar.n)
            bar.set_postfix(ret=f"{entry['return']:.1f}", loss=f"{losses.get('loss', math.nan):.1f}")


def train_updates(model: RSSM, optimizer, store: EpisodeStore, config: PlaNetConfig, run: _RunState,
                  run_dir: Path | None = None) -> dict[str, float]:
    """``config.update_steps`` updates on chunks from ``store``; the mean of each loss term.

    Each update goes through :func:`~wmthesis.training.gradient_step` (gradient norm clipped at
    ``grad_clip``): a non-finite loss term or gradient norm raises
    :class:`~wmthesis.training.NonFiniteLoss` (a ``FloatingPointError``) before the step.
    """
    dev = next(model.parameters()).device
    sums: dict[str, float] = {}
    model.train()
    for _ in range(config.update_steps):
        batch = store.sample_chunks(config.batch_size, config.chunk_length, run.np_rng)
        terms = batch_loss(model, {key: value.to(dev) for key, value in batch.items()}, config, run.torch_rng)
        where = f" in {run_dir}" if run_dir else ""
        gradient_step("PlaNet RSSM", run.updates + 1, terms, optimizer, model.parameters(), clip_norm=config.grad_clip,
                      kept=f"the last good checkpoint (update {_checkpoint_updates(run_dir)}) is kept{where}")
        run.updates += 1
        if run.explorer is not None:
            terms["disagreement"] = _explorer_update(model, run, batch, config, run_dir)
        for key, value in terms.items():
            sums[key] = sums.get(key, 0.0) + float(value.detach())
    return {key: value / config.update_steps for key, value in sums.items()}


def _explorer_update(model: RSSM, run: _RunState, batch: dict, config: PlaNetConfig, run_dir) -> torch.Tensor:
    """One update of the disagreement ensemble on the RSSM's detached features of the same
    chunks (:mod:`~wmthesis.planet.explore`); its loss."""
    dev = next(model.parameters()).device
    data = one_step_batch(model, batch["observations"].to(dev), batch["actions"].to(dev), config.bits, run.updates)
    terms = {"loss": disagreement_loss(run.explorer, *data)}
    gradient_step("disagreement ensemble", run.updates, terms, run.explorer_optimizer, run.explorer.parameters(),
                  kept=f"the last good checkpoint is kept in {run_dir}")
    return terms["loss"]


def batch_loss(model: RSSM, batch: dict[str, torch.Tensor], config: PlaNetConfig,
               generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
    """:func:`~wmthesis.planet.rssm.planet_loss` with the config's knobs on a batch of
    :meth:`~wmthesis.data.EpisodeStore.sample_chunks` (on the model's device)."""
    return planet_loss(model, batch["observations"], batch["actions"], batch["rewards"], bits=config.bits,
                       kl_scale=config.kl_scale, free_nats=config.free_nats,
                       decoder_variance=config.decoder_variance, reward_scale=config.reward_scale,
                       overshooting_distance=config.overshooting_distance,
                       overshooting_scale=config.overshooting_scale,
                       overshooting_reward_scale=config.overshooting_reward_scale,
                       prior_reward_scale=config.prior_reward_scale, reward_event_weight=config.reward_event_weight,
                       generator=generator)


def _copy_run(source: Path, run_dir: Path) -> None:
    """Copy a run's store and checkpoint into ``run_dir`` (the checkpoint last, atomically)."""
    if not (source / CHECKPOINT).exists():
        raise FileNotFoundError(f"{source / CHECKPOINT}: no PlaNet checkpoint to start from")
    for name in (STORE, CHECKPOINT):
        with atomic_path(run_dir / name) as tmp:
            shutil.copyfile(source / name, tmp)


def _checkpoint_updates(run_dir: Path | None):
    path = run_dir / CHECKPOINT if run_dir else None
    if path is None or not path.exists():
        return "none: no checkpoint yet"
    return torch.load(path, map_location="cpu", weights_only=False)["updates"]


def _seed_episodes(store: EpisodeStore, env, config: PlaNetConfig, seed: int) -> None:
    """Random episodes until the store holds ``seed_episodes`` (episode i seeded from (seed, i))."""
    for index in range(len(store), config.seed_episodes):
        store.append_episode(**play_random_episode(env, seed, index))


def _collect_episode(store: EpisodeStore, env, model: RSSM, config: PlaNetConfig, seed: int,
                     explorer=None) -> dict:
    """One epsilon-greedy planner episode, seeded from (seed, its index), into the store (CEM
    with the ``explorer``'s bonus where given)."""
    index = len(store)
    env_seed, mind_seed = episode_seeds(seed, index)
    mind = PlanetMind.from_config(model, config, mind_seed, explorer)
    buffer = EpisodeBuffer()
    model.eval()
    history = loop(env, mind, policy="epsilon-greedy",
                   policy_options={"epsilon": config.epsilon}, callbacks=[mind, buffer],
                   seed=env_seed, train_mode=True)
    store.append_episode(**buffer.episode)
    return {"episode": index, "env_steps": store.num_steps,
            "frames": store.num_steps * _repeat(store, config),
            "return": history[0]["return"], "steps": history[0]["steps"]}


def _test(env, model: RSSM, config: PlaNetConfig, seed: int, store: EpisodeStore, run: _RunState) -> dict:
    """``test_episodes`` greedy episodes; seeds from (seed, episodes in the store, k)."""
    returns = []
    model.eval()
    for k in range(config.test_episodes):
        env_seed, mind_seed = derive_seeds(seed, 1, len(store), k, n=2)
        returns.append(float(sum(play_greedy(env, model, config, env_seed, mind_seed))))
    return {"episode": len(store) - 1, "env_steps": store.num_steps,
            "frames": store.num_steps * _repeat(store, config), "updates": run.updates,
            "returns": returns, "mean": float(np.mean(returns)), "std": float(np.std(returns))}


def _repeat(store: EpisodeStore, config: PlaNetConfig) -> int:
    return config.action_repeat if store.attrs.get("env") in ATARI_GAMES else 1


def _note_unknown_episodes(store: EpisodeStore, known: int | None, run: _RunState, config) -> None:
    """Episodes the checkpoint does not know (a stop between the store's append and the
    checkpoint) are kept as data; their train-curve entries are rebuilt from the store."""
    known = config.seed_episodes if known is None else known
    if len(store) <= known:
        return
    warnings.warn(f"{store.path}: {len(store) - known} episode(s) after the last checkpoint; "
                  "keeping them as data and resuming from the checkpoint", stacklevel=3)
    ends = np.cumsum(store.episode_lengths)
    for index in range(known, len(store)):
        rewards = store.episode(index)["rewards"]
        run.curve["train"].append({"episode": index, "env_steps": int(ends[index]),
                                   "frames": int(ends[index]) * _repeat(store, config),
                                   "return": float(rewards.sum()), "steps": len(rewards),
                                   "updates": run.updates, "recovered": True})


# ---------------------------------------------------------------------------- checkpoints
def _save_checkpoint(run_dir: Path, model, optimizer, run: _RunState, env_name, seed, config, episodes):
    state = {"model": model.state_dict(), "optimizer": optimizer.state_dict(), "updates": run.updates,
             "np_rng": run.np_rng.bit_generator.state, "torch_rng": run.torch_rng.get_state(),
             "curve": run.curve, "seconds": run.seconds, "episodes": episodes, "env": env_name,
             "seed": seed, "config": dataclasses.asdict(config), "n_actions": model.n_actions}
    if run.explorer is not None:
        state.update(explorer=run.explorer.state_dict(), explorer_optimizer=run.explorer_optimizer.state_dict())
    with atomic_path(run_dir / CHECKPOINT) as tmp:
        torch.save(state, tmp)
    with atomic_path(run_dir / CURVE) as tmp:
        tmp.write_text(json.dumps({"env": env_name, "seed": seed, "config": dataclasses.asdict(config),
                                   "updates": run.updates, "seconds": run.seconds, **run.curve}, indent=1))


def _load_checkpoint(path: Path, model, optimizer, run: _RunState, env_name, seed, config) -> int | None:
    """Restore a checkpoint into ``model``, ``optimizer`` and ``run``; return the number of
    episodes it knows (None without a checkpoint)."""
    if not path.exists():
        return None
    state = torch.load(path, map_location=next(model.parameters()).device, weights_only=False)
    if (state["env"], state["seed"]) != (env_name, seed):
        raise ValueError(f"{path}: a run of {state['env']!r} with seed {state['seed']}, not "
                         f"{env_name!r} with seed {seed}; use another run_dir")
    saved, wanted = with_added_defaults(PlaNetConfig, state["config"]), dataclasses.asdict(config)
    differ = sorted(k for k in wanted if k not in RESUMABLE_CHANGES and saved.get(k) != wanted[k])
    if differ:
        changes = ", ".join(f"{k}: {saved.get(k)!r} -> {wanted[k]!r}" for k in differ)
        raise ValueError(f"{path}: cannot resume with a different config ({changes}); use another run_dir")
    model.load_state_dict(state["model"])
    optimizer.load_state_dict(state["optimizer"])
    run.updates, run.curve, run.seconds = state["updates"], state["curve"], state["seconds"]
    run.np_rng.bit_generator.state = state["np_rng"]
    run.torch_rng.set_state(state["torch_rng"].cpu())
    if run.explorer is not None and "explorer" in state:
        run.explorer.load_state_dict(state["explorer"])
        run.explorer_optimizer.load_state_dict(state["explorer_optimizer"])
    return state["episodes"]


def load_planet(run_dir) -> tuple[RSSM, PlaNetConfig, dict]:
    """The trained model (eval mode), its config and the checkpoint's metadata (``env``,
    ``seed``, ``updates``, ``episodes``, ``curve``) from a run folder. A folder without a
    checkpoint that holds the run's agent file (what ships, :mod:`~wmthesis.planet.agent_file`)
    gives that agent's model, its observation decoder left behind (enough to plan and to fit a
    value on, not to decode), with ``shipped`` (the file) as its metadata."""
    path = Path(run_dir) / CHECKPOINT
    if not path.exists():
        if (Path(run_dir) / AGENT_NAME).is_file():
            agent = load_agent(Path(run_dir) / AGENT_NAME)
            return agent.model, agent.planet, {"shipped": str(Path(run_dir) / AGENT_NAME)}
        raise FileNotFoundError(f"{path}: no PlaNet checkpoint (train with train_planet first)")
    state = torch.load(path, map_location=device(), weights_only=False)
    config = PlaNetConfig(**state["config"])
    model = build_model(config, state["n_actions"])
    model.load_state_dict(state["model"])
    model.eval()
    meta = {key: state[key] for key in ("env", "seed", "updates", "episodes", "curve", "seconds")}
    return model, config, meta


def _results(run_dir: Path, env_name, config, store: EpisodeStore, run: _RunState) -> dict:
    tests = run.curve["test"]
    return {"run_dir": str(run_dir), "env": env_name, "config": dataclasses.asdict(config),
            "episodes": len(store), "env_steps": store.num_steps, "updates": run.updates,
            "seconds": run.seconds, "curve": run.curve, "final_test": tests[-1] if tests else None}


def same_training(cached: dict | None, run: dict) -> bool:
    """Whether a cached ``metrics.json`` was written for this training (``run`` as
    :func:`train_planet` returns it): the same updates and the same training curve, so a model
    retrained to the same length is evaluated again."""
    return (cached is not None and cached.get("updates") == run["updates"]
            and cached.get("curve") == json.loads(json.dumps(run["curve"])))  # as a metrics file holds it


__all__ = ["same_training", "train_planet", "train_updates", "batch_loss", "with_variant", "make_planet_env",
           "planet_frame", "PlanetFrames", "build_model", "load_planet"]
