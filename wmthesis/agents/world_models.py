"""World Models pipeline (thesis 4.2, 5.3, 5.4.1): vision, encoded latents, memory, open loop.

    store (frames) --train_vision--> VAE --encode_store--> latents (HDF5: mu, logvar)
    latents --train_memory--> MDN-RNN / deterministic memory --open_loop--> predictions
    Sokoban grid states (5.3.2) --encode_grid_store--> latents of size 64 (no vision)

Every step writes its artifact under a run folder and is skipped (resumed) when re-run.
A checkpoint remembers the store it was trained on (env, preprocessing, latent size) and its
config: training on another store, or resuming with a changed config, fails with a message.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import numpy as np
import torch

from wmthesis.config import MemoryConfig, VisionConfig
from wmthesis.data import EpisodeStore
from wmthesis.metrics import horizon_errors
from wmthesis.models.memory import Memory, Mixture, memory_loss
from wmthesis.models.vae import VAE, elbo_loss, frames_to_input, input_to_frames, sample_latent
from wmthesis.training import train
from wmthesis.utils import atomic_path, device


def split_episodes(n_episodes: int, val_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Train and validation episode indices: the last ``val_fraction`` of episodes validate.

    With a single episode, it serves both (a smoke-sized store)."""
    if n_episodes < 1:
        raise ValueError("the store holds no complete episode")
    n_val = int(round(n_episodes * val_fraction)) if n_episodes > 1 else 0
    n_val = min(max(n_val, 1 if n_episodes > 1 else 0), n_episodes - 1)
    indices = np.arange(n_episodes)
    if n_val == 0:
        return indices, indices
    return indices[:-n_val], indices[-n_val:]


def store_identity(store: EpisodeStore) -> dict:
    """What a model trained on ``store`` depends on: env, preprocessing, observation shape."""
    attrs = store.attrs
    return {"env": attrs.get("env"), "preprocessing": attrs.get("preprocessing"),
            "obs_shape": list(attrs["obs_shape"])}


# ----------------------------------------------------------------------------- vision
def train_vision(store_path: str | Path, run_dir: str | Path, config: VisionConfig, *, seed: int = 0,
                 progress: bool = True) -> tuple[VAE, list[dict]]:
    """Train the VAE on single frames of the store; returns the best model and its history.

    Checkpoint: ``run_dir/vision.pt`` (best weights: ``vision.best.pt``).
    """
    run_dir = Path(run_dir)
    dev = device()
    with EpisodeStore(store_path) as store:
        identity = store_identity(store)
        if tuple(identity["obs_shape"]) != (64, 64, 3):
            raise ValueError(f"{store_path}: vision needs 64x64x3 frames, the store has {identity['obs_shape']}")
        splits = dict(zip(("train", "val"), split_episodes(len(store), config.val_fraction)))
        torch.manual_seed(seed)
        vae = VAE(config.latent_size).to(dev)
        optimiser = torch.optim.Adam(vae.parameters(), lr=config.lr, eps=config.adam_eps)

        def sample(split, rng):
            chunk = store.sample_chunks(config.batch_size, 1, rng, episodes=splits[split])
            return frames_to_input(chunk["observations"][:, 0]).to(dev)

        def loss_fn(x):
            return elbo_loss(x, *vae(x))

        history = train(vae, optimiser, loss_fn, sample, steps=config.steps, checkpoint=run_dir / "vision.pt",
                        config={**dataclasses.asdict(config), **identity}, seed=seed,
                        eval_every=config.eval_every, patience=config.patience, desc="vision", progress=progress)
    return vae.eval(), history


@torch.no_grad()
def reconstruct(vae: VAE, frames: np.ndarray) -> np.ndarray:
    """Zero-step predictions (Fig. 54): frames (N, 64, 64, 3) uint8 -> decoded means, same shape."""
    x = frames_to_input(torch.as_tensor(frames)).to(next(vae.parameters()).device)
    mu, _ = vae.encode(x)
    return input_to_frames(vae.decode(mu)).cpu().numpy()


# ----------------------------------------------------------------------------- latents
def encode_store(store_path: str | Path, vae: VAE, out_path: str | Path, *, batch: int = 512,
                 progress: bool = True) -> Path:
    """Encode every frame of the store once into ``(mu, logvar)``; write them to HDF5.

    The latents file holds ``mu``, ``logvar`` (N, L) float32, ``actions``, ``rewards``,
    ``terminals`` (N,) and ``episode_ends`` (E,), episodes back to back. An existing file
    made from the same store (same episode count and latent size) is kept.
    """
    from tqdm import tqdm

    out_path = Path(out_path)
    dev = next(vae.parameters()).device
    with EpisodeStore(store_path) as store:
        identity = {**store_identity(store), "episodes": len(store), "latent_size": vae.latent_size}
        if out_path.exists() and LatentStore(out_path).identity == identity:
            return out_path
        with atomic_path(out_path) as tmp, h5py.File(tmp, "w") as f:
            f.attrs["identity"] = json.dumps(identity)
            n = store.num_steps
            datasets = {name: f.create_dataset(name, (n, vae.latent_size), np.float32) for name in ("mu", "logvar")}
            scalars = {name: [] for name in ("actions", "rewards", "terminals")}
            row = 0
            for index in tqdm(range(len(store)), desc="encoding", disable=not progress):
                episode = store.episode(index)
                for start in range(0, len(episode["actions"]), batch):
                    frames = torch.as_tensor(episode["observations"][start:start + batch])
                    with torch.no_grad():
                        mu, logvar = vae.encode(frames_to_input(frames).to(dev))
                    datasets["mu"][row:row + len(frames)] = mu.cpu().numpy()
                    datasets["logvar"][row:row + len(frames)] = logvar.cpu().numpy()
                    row += len(frames)
                for name in scalars:
                    scalars[name].append(episode[name])
            for name, parts in scalars.items():
                f.create_dataset(name, data=np.concatenate(parts))
            f.create_dataset("episode_ends", data=np.cumsum(store.episode_lengths))
    return out_path


class LatentStore:
    """An encoded store, held in memory as torch tensors (32 floats + 13 bytes a step).

    ``sample_chunks(batch, length, rng, episodes)`` draws chunks within episodes: a dict of
    ``mu``, ``logvar`` (B, T, L), ``actions`` (B, T) long, ``rewards`` (B, T),
    ``terminals`` (B, T) bool and ``returns`` (B, T) (Monte-Carlo, see :meth:`returns`).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            with h5py.File(self.path, "r") as f:
                self.identity = json.loads(f.attrs["identity"])
                self.data = {name: torch.from_numpy(f[name][:]) for name in ("mu", "logvar", "actions", "rewards", "terminals")}
                self.ends = f["episode_ends"][:]
        except (OSError, KeyError) as error:
            raise ValueError(f"{self.path}: not a readable latents file ({error}); delete it to re-encode") from error
        self.starts = np.concatenate([[0], self.ends[:-1]])
        self.latent_size = self.data["mu"].shape[1]

    def __len__(self) -> int:
        return len(self.ends)

    def returns(self, discount: float) -> torch.Tensor:
        """Discounted Monte-Carlo return from every step to its episode's end, (N,)."""
        rewards = self.data["rewards"].numpy().astype(np.float64)
        out = np.zeros_like(rewards)
        for start, end in zip(self.starts, self.ends):
            total = 0.0
            for t in range(end - 1, start - 1, -1):
                total = rewards[t] + discount * total
                out[t] = total
        return torch.from_numpy(out.astype(np.float32))

    def sample_chunks(self, batch: int, length: int, rng: np.random.Generator, episodes=None,
                      returns: torch.Tensor | None = None) -> dict:
        from wmthesis.data import chunk_starts

        rows = chunk_starts(self.starts, self.ends, batch, length, rng, episodes, where=self.path)
        steps = torch.from_numpy(rows[:, None] + np.arange(length))
        out = {name: tensor[steps] for name, tensor in self.data.items()}
        if returns is not None:
            out["returns"] = returns[steps]
        return out

    def episode(self, index: int) -> dict:
        rows = slice(int(self.starts[index]), int(self.ends[index]))
        return {name: tensor[rows] for name, tensor in self.data.items()}


# ----------------------------------------------------------------------------- memory
def make_memory(latent_size: int, n_actions: int, config: MemoryConfig) -> Memory:
    return Memory(latent_size, n_actions, kind=config.kind, hidden_size=config.hidden_size,
                  n_gaussians=config.n_gaussians, auxiliary=config.auxiliary)


def train_memory(latents_path: str | Path, run_dir: str | Path, config: MemoryConfig, n_actions: int, *,
                 seed: int = 0, progress: bool = True) -> tuple[Memory, list[dict]]:
    """Train the memory on encoded chunks, sampling z ~ N(mu, exp(logvar)) for every batch
    (as the author did). Input (z_t, a_t) predicts z_{t+1}, r_{t+1}, done_{t+1}.

    Checkpoint: ``run_dir/memory-{kind}.pt``.
    """
    latents = LatentStore(latents_path)
    dev = device()
    splits = dict(zip(("train", "val"), split_episodes(len(latents), config.val_fraction)))
    returns = latents.returns(config.discount) if config.auxiliary else None
    torch.manual_seed(seed)
    memory = make_memory(latents.latent_size, n_actions, config).to(dev)
    optimiser = torch.optim.Adam(memory.parameters(), lr=config.lr, eps=config.adam_eps)

    def sample(split, rng):
        chunk = latents.sample_chunks(config.batch_size, config.sequence_length + 1, rng, splits[split], returns)
        return {k: v.to(dev) for k, v in chunk.items()}

    def loss_fn(chunk):
        z = sample_latent(chunk["mu"], chunk["logvar"])
        out = memory(z[:, :-1], chunk["actions"][:, :-1])
        aux = chunk["returns"][:, :-1] if "returns" in chunk else None
        return memory_loss(out, z[:, 1:], chunk["rewards"][:, :-1], chunk["terminals"][:, :-1], aux)

    identity = {**latents.identity, "n_actions": n_actions}
    history = train(memory, optimiser, loss_fn, sample, steps=config.steps,
                    checkpoint=Path(run_dir) / f"memory-{config.kind}.pt",
                    config={**dataclasses.asdict(config), **identity}, seed=seed,
                    eval_every=config.eval_every, patience=config.patience, desc=f"memory ({config.kind})",
                    progress=progress)
    return memory.eval(), history


# ----------------------------------------------------------------------------- open loop
def most_likely(next_latent: Mixture | torch.Tensor) -> torch.Tensor:
    """The memory's point prediction: the mean of the most probable component (``mdn``) or
    the predicted latent (``deterministic``); (..., L)."""
    if not isinstance(next_latent, Mixture):
        return next_latent
    index = next_latent.log_pi.argmax(-1)[..., None, None].expand(*next_latent.log_pi.shape[:-1], 1,
                                                                  next_latent.mu.shape[-1])
    return next_latent.mu.gather(-2, index).squeeze(-2)


@torch.no_grad()
def open_loop(vae: VAE, memory: Memory, frames: np.ndarray, actions: np.ndarray, context: int = 60,
              horizon: int = 30) -> dict:
    """Thesis 5.3: warm the memory on ``context`` real steps, then predict ``horizon`` steps
    feeding back its own point predictions, and decode them.

    ``frames`` (T, 64, 64, 3) uint8 and ``actions`` (T,) of one episode with
    T >= context + horizon. Returns ``truth`` and ``prediction`` frames (horizon, 64, 64, 3),
    ``pixel_error`` and ``latent_error`` curves (horizon,).
    """
    if len(frames) < context + horizon:
        raise ValueError(f"the episode has {len(frames)} steps; open loop needs context + horizon = {context + horizon}")
    dev = next(vae.parameters()).device
    mu, _ = vae.encode(frames_to_input(torch.as_tensor(frames[:context + horizon])).to(dev))
    acts = torch.as_tensor(actions[:context + horizon], dtype=torch.long, device=dev)
    out = memory(mu[None, :context], acts[None, :context])
    z, state, predicted = most_likely(out.next_latent[0, -1] if isinstance(out.next_latent, torch.Tensor)
                                      else Mixture(*(p[0, -1] for p in out.next_latent))), out.state, []
    for t in range(context, context + horizon):
        predicted.append(z)
        step = memory.step(z[None], acts[t][None], state)
        z, state = most_likely(step.next_latent)[0], step.state
    predicted = torch.stack(predicted)
    prediction = input_to_frames(vae.decode(predicted)).cpu().numpy()
    truth = frames[context:context + horizon]
    return {"truth": truth, "prediction": prediction, "pixel_error": horizon_errors(truth, prediction),
            "latent_error": horizon_errors(mu[context:].cpu().numpy(), predicted.cpu().numpy())}


# ----------------------------------------------------------------------------- Sokoban (5.3)
# Grid states as latents (thesis 5.3.2): a 10x10 level's inner 8x8 block types bypass vision.
GRID_NOISE_STD = 0.1


def encode_grid_store(store_path: str | Path, out_path: str | Path, *, noise_std: float = GRID_NOISE_STD) -> Path:
    """Thesis 5.3.2: a store of Sokoban grid observations as a latents file of size 64, no vision.

    The latent of a step is the 64 block codes of the inner 8x8 cells themselves, as floats
    (``mu`` = codes in 0..6, see :data:`wmthesis.envs.sokoban.CELL_NAMES`). Why the integer codes
    and not a one-hot (64 x 7 = 448 numbers): the thesis sets the latent size to 64 and calls
    these 64 block types "the optimal encoding" of a frame; a one-hot would be another, larger
    representation. Its weakness for a linear controller (5.3.2: a box on a target is not a
    feature) is the point of the experiment, so it is kept as the thesis had it.

    ``logvar`` is ``log(noise_std**2)`` everywhere: :func:`train_memory` samples
    ``z ~ N(codes, noise_std**2)`` per batch, a Gaussian dequantisation. Without it the mixture
    density of the MDN on exactly repeated values could grow without bound (its sigmas shrinking
    to zero) and the loss diverge. :func:`decode_grid` rounds a latent back to codes.

    Same layout as :func:`encode_store` (read with :class:`LatentStore`); an existing file made
    from the same store and noise is kept. Returns ``out_path``.
    """
    out_path = Path(out_path)
    with EpisodeStore(store_path) as store:
        identity = {**store_identity(store), "episodes": len(store), "latent_size": int(np.prod(store.obs_shape)),
                    "latent": "grid", "noise_std": float(noise_std)}
        if len(store.obs_shape) != 1:
            raise ValueError(f"{store_path}: grid latents need grid observations (N, cells), "
                             f"the store has {store.obs_shape}")
        if out_path.exists() and LatentStore(out_path).identity == identity:
            return out_path
        episodes = [store.episode(i) for i in range(len(store))]
    with atomic_path(out_path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["identity"] = json.dumps(identity)
        mu = np.concatenate([e["observations"] for e in episodes]).astype(np.float32)
        f.create_dataset("mu", data=mu)
        f.create_dataset("logvar", data=np.full_like(mu, 2 * np.log(noise_std)))
        for name in ("actions", "rewards", "terminals"):
            f.create_dataset(name, data=np.concatenate([e[name] for e in episodes]))
        f.create_dataset("episode_ends", data=np.cumsum([len(e["actions"]) for e in episodes]))
    return out_path


def decode_grid(z: torch.Tensor | np.ndarray, n_codes: int = 7) -> np.ndarray:
    """Grid latents (..., 64) -> block codes (..., 64) uint8: rounded and clipped to 0..n_codes-1."""
    z = z.detach().cpu().numpy() if isinstance(z, torch.Tensor) else np.asarray(z)
    return np.clip(np.rint(z), 0, n_codes - 1).astype(np.uint8)


class GridVision:
    """Vision for grid observations (5.3.2): uint8 codes (N, 64) -> the codes as float latents
    (N, 64); no model (for :func:`~wmthesis.agents.controller_training.train_controller`)."""

    def __init__(self, latent_size: int = 64):
        self.latent_size = latent_size

    def __call__(self, grids: torch.Tensor) -> torch.Tensor:
        return grids.float()


@torch.no_grad()
def rollout_latents(memory: Memory, z: torch.Tensor, actions: torch.Tensor, context: int, horizon: int) -> torch.Tensor:
    """The memory's open-loop latents (thesis 5.3), as in :func:`open_loop` but on latents:
    read ``context`` real ``(z, a)`` steps, then predict ``horizon`` steps feeding back its own
    point predictions (:func:`most_likely`). ``z`` (T, L), ``actions`` (T,) long with
    T >= context + horizon; returns the predictions of ``z[context:context + horizon]``, (horizon, L).
    """
    out = memory(z[None, :context], actions[None, :context])
    last = (out.next_latent[0, -1] if isinstance(out.next_latent, torch.Tensor)
            else Mixture(*(p[0, -1] for p in out.next_latent)))
    prediction, state, predicted = most_likely(last), out.state, []
    for t in range(context, context + horizon):
        predicted.append(prediction)
        step = memory.step(prediction[None], actions[t][None], state)
        prediction, state = most_likely(step.next_latent)[0], step.state
    return torch.stack(predicted)


@torch.no_grad()
def open_loop_grid(memory: Memory, grids: np.ndarray, actions: np.ndarray, context: int = 60, horizon: int = 30,
                   inner_shape=(8, 8)) -> dict:
    """:func:`open_loop` for a memory over grid latents (5.3.2): the predicted latents are
    rounded to block codes and drawn as World Models frames
    (:func:`~wmthesis.envs.sokoban.grid_frames`), so their pixel error is comparable with the
    VAE variants'. ``grids`` (T, 64) uint8 codes, ``actions`` (T,) of one episode.

    Returns ``truth`` and ``prediction`` frames (horizon, 64, 64, 3), ``truth_grid`` and
    ``prediction_grid`` codes (horizon, 64), ``pixel_error`` and ``latent_error`` (squared
    error of the unrounded latents, in code units) curves (horizon,).
    """
    from wmthesis.envs.sokoban import grid_frames

    if len(grids) < context + horizon:
        raise ValueError(f"the episode has {len(grids)} steps; open loop needs context + horizon = {context + horizon}")
    dev = next(memory.parameters()).device
    z = torch.as_tensor(np.asarray(grids[:context + horizon]), dtype=torch.float32, device=dev)
    acts = torch.as_tensor(actions[:context + horizon], dtype=torch.long, device=dev)
    predicted = rollout_latents(memory, z, acts, context, horizon)
    truth_grid = np.asarray(grids[context:context + horizon], np.uint8)
    prediction_grid = decode_grid(predicted)
    truth, prediction = grid_frames(truth_grid, inner_shape), grid_frames(prediction_grid, inner_shape)
    return {"truth": truth, "prediction": prediction, "truth_grid": truth_grid, "prediction_grid": prediction_grid,
            "pixel_error": horizon_errors(truth, prediction),
            "latent_error": horizon_errors(z[context:].cpu().numpy(), predicted.cpu().numpy())}


def grid_accuracy(predicted: np.ndarray, truth: np.ndarray, last_seen: np.ndarray, num_boxes: int = 4) -> dict:
    """What the thesis saw by eye in Fig. 55, as numbers per horizon step (averaged over episodes).

    ``predicted``, ``truth``: block codes (E, T, C) of E open-loop rollouts; ``last_seen``:
    (E, C), the last real grid the memory read. Returns (T,) curves: ``cell_accuracy`` (cells of
    the right type), ``changed_cell_accuracy`` (the same over the cells that changed since
    ``last_seen``: the dynamics; NaN where none changed), ``one_player`` (rollouts showing exactly
    one player: "the agent disappears") and ``boxes_kept`` (exactly ``num_boxes`` boxes).
    """
    from wmthesis.envs.sokoban import BOX, BOX_ON_TARGET, PLAYER, PLAYER_ON_TARGET

    predicted, truth = np.asarray(predicted), np.asarray(truth)
    right = predicted == truth
    changed = truth != np.asarray(last_seen)[:, None]
    n_changed = changed.sum((0, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        changed_accuracy = np.where(n_changed > 0, (right & changed).sum((0, 2)) / n_changed, np.nan)
    players = np.isin(predicted, (PLAYER, PLAYER_ON_TARGET)).sum(-1)
    boxes = np.isin(predicted, (BOX, BOX_ON_TARGET)).sum(-1)
    return {"cell_accuracy": right.mean((0, 2)), "changed_cell_accuracy": changed_accuracy,
            "one_player": (players == 1).mean(0), "boxes_kept": (boxes == num_boxes).mean(0)}


@torch.no_grad()
def head_predictions(memory: Memory, z: torch.Tensor | np.ndarray, actions) -> dict:
    """The memory's reward (and value, with auxiliary heads) predictions along one real episode
    (teacher forcing: it reads the true latents). ``z`` (T, L), ``actions`` (T,); returns
    ``reward`` (T,) (the reward of each step's action) and ``value`` (T,) or None."""
    dev = next(memory.parameters()).device
    z = torch.as_tensor(np.asarray(z), dtype=torch.float32, device=dev)
    out = memory(z[None], torch.as_tensor(np.asarray(actions), dtype=torch.long, device=dev)[None])
    return {"reward": out.reward[0].cpu().numpy(),
            "value": None if out.value is None else out.value[0].cpu().numpy()}
