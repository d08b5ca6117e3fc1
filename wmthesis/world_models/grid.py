"""Grid states as latents (thesis 5.3.2): a 10x10 Sokoban level's inner 8x8 block types, as
64 integer codes, stand in for the VAE's latents and bypass vision."""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import torch

from wmthesis.data import EpisodeStore
from wmthesis.envs.sokoban import BOX, BOX_ON_TARGET, PLAYER, PLAYER_ON_TARGET
from wmthesis.runs import atomic_path
from wmthesis.world_models.train import LatentStore, store_identity

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
    (N, 64); no model (for :func:`~wmthesis.world_models.evolution.train_controller`)."""

    def __init__(self, latent_size: int = 64):
        self.latent_size = latent_size

    def __call__(self, grids: torch.Tensor) -> torch.Tensor:
        return grids.float()


def grid_accuracy(predicted: np.ndarray, truth: np.ndarray, last_seen: np.ndarray, num_boxes: int = 4) -> dict:
    """What the thesis saw by eye in Fig. 55, as numbers per horizon step (averaged over episodes).

    ``predicted``, ``truth``: block codes (E, T, C) of E open-loop rollouts; ``last_seen``:
    (E, C), the last real grid the memory read. Returns (T,) curves: ``cell_accuracy`` (cells of
    the right type), ``changed_cell_accuracy`` (the same over the cells that changed since
    ``last_seen``: the dynamics; NaN where none changed), ``one_player`` (rollouts showing exactly
    one player: "the agent disappears") and ``boxes_kept`` (exactly ``num_boxes`` boxes).
    """
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
