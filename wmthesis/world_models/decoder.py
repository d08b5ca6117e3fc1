"""The vision's decoder (thesis 4.2.5, Fig. 44), kept in a file of its own beside the agents that
see through its encoder.

An agent file keeps only the VAE's encoder (playing only encodes). Drawing what the agent sees
and dreams (Fig. 56 and 57) needs the decoder: :func:`fit_decoder` fits one to a frozen encoder
(the encoder, and so every agent and score built on it, unchanged) with the ELBO's
reconstruction term on the encoder's reparameterised samples, and :func:`save_decoder` writes
it (its weights as int8 with a scale per output slice) with the fingerprint of the encoder it decodes and what it was fitted on.
:func:`attach_decoder` puts a decoder file's weights into a loaded vision after checking the
fingerprint; a vision without one decodes nothing (:class:`MissingDecoder`).

    vae, history = fit_decoder(vae, store_path, run_dir, VisionConfig(...), seed=0)
    save_decoder(folder / DECODER_NAME, vae, fitted_on={...})
    attach_decoder(vision.vae, folder / DECODER_NAME)   # then vision.decode(z)
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from wmthesis.data import EpisodeStore
from wmthesis.runs import read_agent_file, save_agent_file
from wmthesis.training import train
from wmthesis.utils import fingerprint
from wmthesis.world_models.config import VisionConfig
from wmthesis.world_models.train import split_episodes, store_identity
from wmthesis.world_models.vision import VAE, Decoder, frames_to_input, sample_latent

FORMAT = "wmthesis-vision-decoder"
FORMAT_VERSION = 1
DECODER_NAME = "decoder.pt"


class MissingDecoder(torch.nn.Module):
    """Where a vision's decoder would be: decoding raises an error naming what is missing."""

    def __init__(self, why: str):
        super().__init__()
        self.why = why

    def forward(self, z):
        raise RuntimeError(self.why)


class FrozenEncoder(torch.nn.Module):
    """The VAE with its encoder frozen: the decoder's parameters alone train (``parameters``)."""

    def __init__(self, vae: VAE):
        super().__init__()
        self.vae = vae
        for name, p in vae.named_parameters():
            p.requires_grad_(name.startswith("decoder."))

    def parameters(self, recurse: bool = True):
        return self.vae.decoder.parameters(recurse)

    def state_dict(self, *args, **kwargs):
        return self.vae.decoder.state_dict(*args, **kwargs)

    def load_state_dict(self, state, strict: bool = True, assign: bool = False):
        return self.vae.decoder.load_state_dict(state, strict, assign)

    def train(self, mode: bool = True):
        self.vae.eval()  # the encoder's statistics stay as they were (it has none; kept for the pattern)
        self.vae.decoder.train(mode)
        return self


def encoder_fingerprint(vae: VAE) -> str:
    """A hash of the encoder's weights (the decoder's left out): what a decoder file is for."""
    encoder = torch.nn.ModuleDict({"encoder": vae.encoder, "mu": vae.mu, "logvar": vae.logvar})
    return fingerprint(encoder)


def fit_decoder(vae: VAE, store_path: str | Path, run_dir: str | Path, config: VisionConfig, *, seed: int = 0,
                progress: bool = True) -> tuple[VAE, list[dict]]:
    """Fit ``vae``'s decoder (re-initialised from ``seed``) to its frozen encoder on single
    64x64x3 frames of the store, minimising the negative Bernoulli log-likelihood of a frame
    given one reparameterised sample of its latent (the ELBO's first term; the KL term does not
    depend on the decoder). ``config``: batch size, updates, evaluation and patience as the
    vision's own training. Resumable from ``run_dir/decoder-fit.pt``; returns the VAE with the
    best decoder on the validation episodes, and the history."""
    torch.manual_seed(seed)
    vae.decoder = Decoder(vae.latent_size).to(next(vae.encoder.parameters()).device)
    model = FrozenEncoder(vae)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.lr, eps=config.adam_eps)
    dev = next(vae.encoder.parameters()).device
    with EpisodeStore(store_path) as store:
        identity = store_identity(store)
        splits = dict(zip(("train", "val"), split_episodes(len(store), config.val_fraction)))

        def sample(split, rng):
            chunk = store.sample_chunks(config.batch_size, 1, rng, episodes=splits[split])
            return frames_to_input(chunk["observations"][:, 0]).to(dev)

        def loss_fn(x):
            with torch.no_grad():
                mu, logvar = vae.encode(x)
            logits = vae.decode_logits(sample_latent(mu, logvar))
            reconstruction = F.binary_cross_entropy_with_logits(logits, x, reduction="none").flatten(1).sum(1).mean()
            return {"loss": reconstruction, "reconstruction": reconstruction}

        history = train(model, optimiser, loss_fn, sample, steps=config.steps,
                        checkpoint=Path(run_dir) / "decoder-fit.pt",
                        config={**dataclasses.asdict(config), **identity, "encoder": encoder_fingerprint(vae)},
                        seed=seed, eval_every=config.eval_every, patience=config.patience, desc="decoder",
                        progress=progress)
    for p in vae.parameters():
        p.requires_grad_(True)
    return vae.eval(), history


def save_decoder(path: str | os.PathLike, vae: VAE, fitted_on: dict) -> Path:
    """``vae``'s decoder at ``path`` (:func:`compact`: about 3.6 MB for the VAE's), with its encoder's fingerprint and
    ``fitted_on`` (what it was fitted on and how: it says that the decoder came afterwards)."""
    state = {k: compact(v) for k, v in vae.decoder.state_dict().items()}
    return save_agent_file(path, FORMAT, FORMAT_VERSION, latent_size=vae.latent_size,
                           encoder=encoder_fingerprint(vae), decoder=state, fitted_on=fitted_on)


def compact(weight: torch.Tensor):
    """A weight as it ships: a matrix or kernel (ndim >= 2) as int8 with one float scale per slice
    of its first dimension (``{"int8", "scale"}``, a quarter of float32's bytes), anything else in
    half precision."""
    weight = weight.detach().cpu().float()
    if weight.ndim < 2:
        return weight.half()
    scale = weight.abs().flatten(1).amax(1).clamp(min=1e-12) / 127
    shape = (-1,) + (1,) * (weight.ndim - 1)
    return {"int8": torch.round(weight / scale.view(shape)).to(torch.int8), "scale": scale}


def expanded(saved) -> torch.Tensor:
    """:func:`compact`'s weight back in float32."""
    if isinstance(saved, dict):
        return saved["int8"].float() * saved["scale"].view((-1,) + (1,) * (saved["int8"].ndim - 1))
    return saved.float()


def attach_decoder(vae: VAE, path: str | os.PathLike) -> dict:
    """Load the decoder file at ``path`` into ``vae`` (in float32); returns its ``fitted_on``.
    A missing or foreign file, or one fitted to another encoder, raises an error naming it."""
    path = Path(path)
    saved = read_agent_file(path, "vision decoder", FORMAT, FORMAT_VERSION)
    if saved["encoder"] != encoder_fingerprint(vae):
        raise ValueError(f"{path} decodes the encoder {saved['encoder']}, not this vision's "
                         f"({encoder_fingerprint(vae)})")
    if isinstance(vae.decoder, MissingDecoder):
        vae.decoder = Decoder(vae.latent_size)
    vae.decoder.load_state_dict({k: expanded(v) for k, v in saved["decoder"].items()})
    vae.decoder.to(next(vae.encoder.parameters()).device).eval()
    return saved["fitted_on"]


def reconstruction_error(vae: VAE, frames: np.ndarray) -> float:
    """Mean absolute pixel error (in [0, 1]) of ``frames`` (N, 64, 64, 3) uint8 decoded from
    their latent means."""
    with torch.no_grad():
        x = frames_to_input(torch.as_tensor(frames)).to(next(vae.parameters()).device)
        return float((vae.decode(vae.encode(x)[0]) - x).abs().mean())


__all__ = ["FORMAT", "FORMAT_VERSION", "DECODER_NAME", "MissingDecoder", "encoder_fingerprint", "fit_decoder",
           "save_decoder", "attach_decoder", "reconstruction_error"]
