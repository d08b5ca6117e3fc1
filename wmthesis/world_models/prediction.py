"""What the memory predicts (thesis 5.3): open-loop rollouts from its own predictions, in
pixels (through the VAE) or in grid states, and its reward/value heads under teacher forcing."""
from __future__ import annotations

import numpy as np
import torch

from wmthesis.envs.sokoban import grid_frames
from wmthesis.metrics import horizon_errors
from wmthesis.world_models.grid import decode_grid
from wmthesis.world_models.memory import Memory, Mixture
from wmthesis.world_models.vision import VAE, frames_to_input, input_to_frames


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


def open_loop_errors(vae, memory, episode: dict, context: int, horizon: int, starts: int = 8) -> dict:
    """The open-loop error by horizon averaged over up to ``starts`` rollouts of one episode
    (starting every ``context + horizon`` steps), beside the "nothing moves" baseline that
    repeats the last context frame. Returns ``pixel_error``, ``latent_error`` and
    ``still_pixel_error`` (horizon,) and ``rollouts``."""
    frames, actions, span = episode["observations"], episode["actions"], context + horizon
    pixel, latent, still = [], [], []
    for t0 in range(0, len(frames) - span + 1, span)[:starts]:
        rollout = open_loop(vae, memory, frames[t0:], actions[t0:], context=context, horizon=horizon)
        pixel.append(rollout["pixel_error"])
        latent.append(rollout["latent_error"])
        still.append(horizon_errors(rollout["truth"], np.repeat(frames[t0 + context - 1][None], horizon, 0)))
    if not pixel:
        raise ValueError(f"the episode has {len(frames)} steps; open loop needs context + horizon = {span}")
    return {"pixel_error": np.mean(pixel, 0), "latent_error": np.mean(latent, 0),
            "still_pixel_error": np.mean(still, 0), "rollouts": len(pixel)}
