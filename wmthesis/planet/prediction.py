"""What the RSSM predicts (thesis 5.5-5.6, Fig. 58-510): filter a few real frames, then
imagine the rest open-loop from the actions taken, and compare with the truth."""
from __future__ import annotations

import numpy as np
import torch

from wmthesis.data import EpisodeStore
from wmthesis.envs.preprocessing import to_float
from wmthesis.planet.rssm import RSSM, frames_out, one_hot_previous


@torch.inference_mode()
def open_loop(model: RSSM, observations: torch.Tensor, actions: torch.Tensor, *, context: int = 5,
              bits: int = 5, generator: torch.Generator | None = None, sample: bool = False) -> dict:
    """Filter ``context`` frames, then predict the rest open-loop from the actions taken.

    ``observations`` (B, T, H, W, 3) uint8, ``actions`` (B, T) long (row t: ``a_t``). The
    frames after the context are decoded from the prior (its means; samples with
    ``sample=True``). Returns numpy arrays: ``truth`` and ``prediction`` (B, T, H, W, 3)
    uint8 (the first ``context`` predictions are the posterior reconstructions), and ``mse``
    (T - context,): the squared error per pixel of each horizon, averaged over the batch, in
    the model's float units (frames in [-0.5, 0.5), the truth at its bins' centres).
    """
    if not 1 <= context < observations.shape[1]:
        raise ValueError(f"context must be in 1..T-1, got {context} for T = {observations.shape[1]}")
    dev = next(model.parameters()).device
    truth = to_float(observations.to(dev), bits) + 0.5 / 2 ** bits
    prev_actions = one_hot_previous(actions.to(dev), model.n_actions)
    trajectory = model.observe(model.encode(truth[:, :context]), prev_actions[:, :context], generator)
    beliefs, states = model.imagine(trajectory.beliefs[:, -1], trajectory.states[:, -1],
                                    prev_actions[:, context:], generator, sample)
    predicted = model.decode(beliefs, states)
    reconstructed = model.decode(trajectory.beliefs, trajectory.states)
    mse = (predicted - truth[:, context:]).pow(2).mean((0, 2, 3, 4))
    prediction = frames_out(torch.cat([reconstructed, predicted], 1), bits)
    return {"truth": observations.cpu().numpy(), "prediction": prediction.cpu().numpy(),
            "mse": mse.cpu().numpy(), "context": context}


def evaluate_open_loop(model: RSSM, store: EpisodeStore, *, sequences: int = 6, length: int = 20,
                       context: int = 5, bits: int = 5, seed: int = 0) -> dict:
    """:func:`open_loop` on ``sequences`` random chunks of ``length`` steps from ``store``."""
    batch = store.sample_chunks(sequences, length, np.random.default_rng(seed))
    generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
    return open_loop(model, batch["observations"], batch["actions"], context=context, bits=bits,
                     generator=generator)
