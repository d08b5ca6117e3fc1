"""What the RSSM predicts (thesis 5.5-5.6, Fig. 58-510): filter a few real frames, then
imagine the rest open-loop from the actions taken, and compare with the truth: on every pixel
(:func:`open_loop`'s ``mse``) and on the moving pixels only (:func:`moving_open_loop`), where a
blurry mean frame cannot score well, against the baselines "repeat the last context frame" and
"the mean frame"."""
from __future__ import annotations

import math

import numpy as np
import torch

from wmthesis.data import EpisodeStore
from wmthesis.envs.preprocessing import to_float
from wmthesis.planet.rssm import RSSM, frames_out, kl_divergence, one_hot_previous


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


# ---------------------------------------------------------------------------- moving pixels
MOVING_TOLERANCE = 32  # uint8 levels (4 steps of 5-bit frames): smaller differences are background


def background_frame(frames: np.ndarray) -> np.ndarray:
    """The static background of a game: the per-pixel median of frames (N, H, W, 3) uint8
    -> (H, W, 3) uint8 (what stays put, as the ring and the floor in Boxing)."""
    return np.median(np.asarray(frames), axis=0).astype(np.uint8)


def moving_mask(frames: np.ndarray, background: np.ndarray, tolerance: int = MOVING_TOLERANCE) -> np.ndarray:
    """Pixels that differ from the background: frames (..., H, W, 3) -> bool (..., H, W),
    True where any channel is more than ``tolerance`` levels away."""
    diff = np.abs(np.asarray(frames, np.int16) - background.astype(np.int16))
    return diff.max(-1) > tolerance


def moving_error(truth: np.ndarray, prediction: np.ndarray, background: np.ndarray,
                 tolerance: int = MOVING_TOLERANCE) -> np.ndarray:
    """Squared error per channel on the moving pixels, by time: truth and prediction
    (B, T, H, W, 3) uint8 -> (T,) in [0, 1] units (differences / 255).

    A pixel counts where the truth OR the prediction differs from the background, so a
    prediction that blurs or misplaces the moving objects pays for both places, and one that
    shows only the background pays for every moving pixel; the background alone cannot score.
    """
    mask = moving_mask(truth, background, tolerance) | moving_mask(prediction, background, tolerance)
    squared = ((truth.astype(np.float32) - prediction.astype(np.float32)) / 255.0) ** 2
    per_time = (squared.mean(-1) * mask).sum((0, 2, 3))
    return per_time / np.maximum(mask.sum((0, 2, 3)), 1)


def baseline_predictions(truth: np.ndarray, context: int, mean_frame: np.ndarray) -> dict[str, np.ndarray]:
    """The two open-loop baselines for ``truth`` (B, T, H, W, 3) uint8: ``repeat last`` (the
    last context frame, forever) and ``mean frame`` (the training data's mean frame, uint8),
    each (B, T - context, H, W, 3)."""
    horizon = truth.shape[1] - context
    last = np.repeat(truth[:, context - 1:context], horizon, axis=1)
    mean = np.broadcast_to(mean_frame, last.shape)
    return {"repeat last": last, "mean frame": mean}


def moving_open_loop(model: RSSM, observations: torch.Tensor, actions: torch.Tensor, *,
                     background: np.ndarray, mean_frame: np.ndarray, context: int = 5, bits: int = 5,
                     seed: int = 0) -> dict:
    """:func:`open_loop` scored on the moving pixels (:func:`moving_error`) against the two
    baselines. Returns ``model``, ``repeat last`` and ``mean frame``: errors by horizon
    (T - context,); ``filtered``: the same error of the context frames' reconstructions from the
    posterior (``model``) and of the mean frame, (context,) each (does the model see what moves
    in the frames it is given?); and ``rollout``: the :func:`open_loop` result."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
    rollout = open_loop(model, observations, actions, context=context, bits=bits, generator=generator)
    truth, seen = rollout["truth"][:, context:], rollout["truth"][:, :context]
    errors = {"model": moving_error(truth, rollout["prediction"][:, context:], background)}
    for name, frames in baseline_predictions(rollout["truth"], context, mean_frame).items():
        errors[name] = moving_error(truth, frames, background)
    filtered = {"model": moving_error(seen, rollout["prediction"][:, :context], background),
                "mean frame": moving_error(seen, np.broadcast_to(mean_frame, seen.shape), background)}
    return {**errors, "filtered": filtered, "rollout": rollout}


@torch.inference_mode()
def latent_diagnostics(model: RSSM, observations: torch.Tensor, actions: torch.Tensor, *,
                       bits: int = 5, seed: int = 0) -> dict[str, float]:
    """Why a KL scale does or does not matter (thesis 5.6.3-5.6.4), on filtered chunks
    (B, T, H, W, 3) uint8 and actions (B, T): the mean ``kl`` KL[q || p] per step (to set
    against the free nats), the mean ``posterior_entropy`` and ``prior_entropy`` of the
    stochastic state (nats, summed over its dimensions), and the ``embedding_spread``: the
    encoder's output, its standard deviation over the B x T frames averaged over its features
    (near 0, the encoder answers every frame alike and the posterior cannot see them)."""
    dev = next(model.parameters()).device
    generator = torch.Generator(dev).manual_seed(seed)
    frames = to_float(observations.to(dev), bits) + 0.5 / 2 ** bits
    embedded = model.encode(frames)                                          # (B, T, E)
    trajectory = model.observe(embedded, one_hot_previous(actions.to(dev), model.n_actions), generator)
    entropy = lambda g: (0.5 * math.log(2 * math.pi * math.e) + g.std.log()).sum(-1).mean()  # noqa: E731
    return {"kl": float(kl_divergence(trajectory.posterior, trajectory.prior).mean()),
            "posterior_entropy": float(entropy(trajectory.posterior)),
            "prior_entropy": float(entropy(trajectory.prior)),
            "embedding_spread": float(embedded.flatten(0, 1).std(0).mean())}


@torch.inference_mode()
def planned_path(model: RSSM, belief: torch.Tensor, state: torch.Tensor,
                 actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What the model imagines along a plan: from ``(h, s)`` (1, H), (1, S), the ``actions`` (T,)
    long followed on the prior's means; beliefs (T, H), states (T, S) and the rewards it predicts (T,)."""
    along = torch.nn.functional.one_hot(actions.long(), model.n_actions).float()[None]
    steps = [(step.belief, step.state) for step in model.imagined_steps(belief, state, along, lambda prior: prior.mean)]
    beliefs, states = torch.cat([b for b, _ in steps]), torch.cat([s for _, s in steps])
    return beliefs, states, model.reward(beliefs, states)
