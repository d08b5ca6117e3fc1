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
from tqdm import tqdm

from wmthesis.data import EpisodeStore, chunk_starts
from wmthesis.runs import atomic_path
from wmthesis.training import train
from wmthesis.utils import device, fingerprint
from wmthesis.world_models.config import MemoryConfig, VisionConfig
from wmthesis.world_models.memory import Memory, memory_loss
from wmthesis.world_models.vision import VAE, elbo_loss, frames_to_input, input_to_frames, sample_latent


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

    @property
    def num_steps(self) -> int:
        """Steps over every episode."""
        return int(self.ends[-1]) if len(self.ends) else 0

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
                 seed: int = 0, progress: bool = True, initial: Memory | None = None,
                 reward_weight: float = 1.0) -> tuple[Memory, list[dict]]:
    """Train the memory on encoded chunks, sampling z ~ N(mu, exp(logvar)) for every batch
    (as the author did). Input (z_t, a_t) predicts z_{t+1}, r_{t+1}, done_{t+1}. ``initial``: a
    memory whose weights it starts from (None: fresh ones); ``reward_weight``: the weight of a
    step with a reward in the reward and done terms, against 1 for the rest (rare rewards balanced).

    Checkpoint: ``run_dir/memory-{kind}.pt``.
    """
    latents = LatentStore(latents_path)
    dev = device()
    splits = dict(zip(("train", "val"), split_episodes(len(latents), config.val_fraction)))
    returns = latents.returns(config.discount) if config.auxiliary else None
    torch.manual_seed(seed)
    memory = make_memory(latents.latent_size, n_actions, config).to(dev)
    if initial is not None:
        memory.load_state_dict(initial.state_dict())
    optimiser = torch.optim.Adam(memory.parameters(), lr=config.lr, eps=config.adam_eps)

    def sample(split, rng):
        chunk = latents.sample_chunks(config.batch_size, config.sequence_length + 1, rng, splits[split], returns)
        return {k: v.to(dev) for k, v in chunk.items()}

    def loss_fn(chunk):
        z = sample_latent(chunk["mu"], chunk["logvar"])
        out = memory(z[:, :-1], chunk["actions"][:, :-1])
        aux = chunk["returns"][:, :-1] if "returns" in chunk else None
        return memory_loss(out, z[:, 1:], chunk["rewards"][:, :-1], chunk["terminals"][:, :-1], aux, reward_weight)

    identity = {**latents.identity, "n_actions": n_actions, **({"reward_weight": reward_weight} if reward_weight != 1.0
                                                              else {}), **({"warm_start": fingerprint(initial)}
                                                                          if initial is not None else {})}
    history = train(memory, optimiser, loss_fn, sample, steps=config.steps,
                    checkpoint=Path(run_dir) / f"memory-{config.kind}.pt",
                    config={**dataclasses.asdict(config), **identity}, seed=seed,
                    eval_every=config.eval_every, patience=config.patience, desc=f"memory ({config.kind})",
                    progress=progress)
    return memory.eval(), history
