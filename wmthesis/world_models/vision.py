"""Vision: the convolutional VAE of World Models (thesis 4.2.5, Fig. 44).

Encoder (64x64x3 input): conv 32, 64, 128, 256 channels, kernel 4, stride 2, ReLU
-> (B, 256, 2, 2) -> flatten 1024 -> linear heads for ``mu`` and ``logvar`` (latent size L).
Decoder: linear L -> 1024 -> (B, 1024, 1, 1) -> deconv 128, 64, 32 (ReLU) and 3 (sigmoid)
with kernels 5, 5, 6, 6 and stride 2 -> (B, 3, 64, 64) in [0, 1].

ELBO (per image, to maximise), with a Bernoulli observation model as in the thesis (4.2.1):

    ELBO(x) = E_q(z|x)[ log p(x|z) ] - KL( q(z|x) || N(0, I) )
    log p(x|z) = sum_pixels x log x_hat + (1 - x) log(1 - x_hat)
    KL = 0.5 * sum_j ( mu_j^2 + exp(logvar_j) - logvar_j - 1 )

The loss is -ELBO averaged over the batch (summed over pixels and latent dimensions),
estimated with one reparameterised sample z = mu + exp(logvar / 2) * eps.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.utils import check_finite


class Encoder(nn.Module):
    """(B, 3, 64, 64) float in [0, 1] -> features (B, 1024)."""

    frame_size = 64

    def __init__(self, channels: int = 3):
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv2d(channels, 32, 4, stride=2), nn.ReLU(),
            nn.Conv2d(32, 64, 4, stride=2), nn.ReLU(),
            nn.Conv2d(64, 128, 4, stride=2), nn.ReLU(),
            nn.Conv2d(128, 256, 4, stride=2), nn.ReLU(),
            nn.Flatten())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.convs(x)


class Decoder(nn.Module):
    """Features (B, F) -> image logits (B, 3, 64, 64) (apply a sigmoid for pixels)."""

    def __init__(self, in_features: int, channels: int = 3):
        super().__init__()
        self.fc = nn.Linear(in_features, 1024)
        self.deconvs = nn.Sequential(
            nn.ConvTranspose2d(1024, 128, 5, stride=2), nn.ReLU(),
            nn.ConvTranspose2d(128, 64, 5, stride=2), nn.ReLU(),
            nn.ConvTranspose2d(64, 32, 6, stride=2), nn.ReLU(),
            nn.ConvTranspose2d(32, channels, 6, stride=2))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.deconvs(self.fc(features)[:, :, None, None])


class VAE(nn.Module):
    """The vision module: ``encode`` frames to (mu, logvar), ``decode`` latents to frames."""

    def __init__(self, latent_size: int = 16):
        super().__init__()
        self.latent_size = latent_size
        self.encoder = Encoder()
        self.mu = nn.Linear(1024, latent_size)
        self.logvar = nn.Linear(1024, latent_size)
        self.decoder = Decoder(latent_size)

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 3, 64, 64) in [0, 1] -> ``mu``, ``logvar``, each (B, L)."""
        features = self.encoder(x)
        return self.mu(features), self.logvar(features)

    def decode_logits(self, z: torch.Tensor) -> torch.Tensor:
        """(B, L) -> logits (B, 3, 64, 64)."""
        return self.decoder(z)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """(B, L) -> frames (B, 3, 64, 64) in [0, 1]."""
        return torch.sigmoid(self.decoder(z))

    def forward(self, x: torch.Tensor, generator: torch.Generator | None = None):
        """(B, 3, 64, 64) -> ``(logits, mu, logvar)`` with one reparameterised sample."""
        mu, logvar = self.encode(x)
        z = sample_latent(mu, logvar, generator)
        return self.decode_logits(z), mu, logvar


def sample_latent(mu: torch.Tensor, logvar: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """z = mu + exp(logvar / 2) * eps, eps ~ N(0, I); shapes (..., L)."""
    eps = torch.randn(mu.shape, generator=generator, device=mu.device, dtype=mu.dtype)
    return mu + torch.exp(0.5 * logvar) * eps


def kl_to_standard_normal(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mu, exp(logvar)) || N(0, I)) summed over the last dimension: (..., L) -> (...)."""
    return 0.5 * (mu.pow(2) + logvar.exp() - logvar - 1).sum(-1)


def elbo_loss(x: torch.Tensor, logits: torch.Tensor, mu: torch.Tensor, logvar: torch.Tensor) -> dict:
    """-ELBO averaged over the batch, with its two terms (see the module docstring).

    ``x`` and ``logits``: (B, 3, 64, 64); ``mu``, ``logvar``: (B, L). Returns a dict of scalars
    ``loss``, ``reconstruction`` (negative Bernoulli log-likelihood) and ``kl``.
    """
    reconstruction = F.binary_cross_entropy_with_logits(logits, x, reduction="none").flatten(1).sum(1).mean()
    kl = kl_to_standard_normal(mu, logvar).mean()
    return {"loss": reconstruction + kl, "reconstruction": reconstruction, "kl": kl}


def frames_to_input(frames: torch.Tensor) -> torch.Tensor:
    """uint8 frames (..., 64, 64, 3) -> float (..., 3, 64, 64) in [0, 1]."""
    return frames.movedim(-1, -3).float().div_(255)


def input_to_frames(x: torch.Tensor) -> torch.Tensor:
    """float (..., 3, 64, 64) in [0, 1] -> uint8 frames (..., 64, 64, 3)."""
    return x.clamp(0, 1).mul(255).round().to(torch.uint8).movedim(-3, -1)


class VAEVision:
    """The VAE's encoder as vision: uint8 frames (N, 64, 64, 3) -> latent means ``mu`` (N, L).

    ``bfloat16=True`` encodes under bfloat16 autocast: about twice as fast on a CPU with
    AVX-512 BF16, latents within ~1e-2 of float32 (use the same vision to train and to play).
    Frames and latents may be numpy arrays or torch tensors; nothing tracks gradients.
    :meth:`decode` needs the VAE's decoder (a shipped agent's ``decoder.pt``): without it, it
    raises an error saying so.
    """

    def __init__(self, vae: torch.nn.Module, bfloat16: bool = False):
        self.vae, self.bfloat16 = vae.eval(), bfloat16
        self.latent_size = vae.latent_size

    @torch.no_grad()
    def __call__(self, frames) -> torch.Tensor:
        frames = check_frames(frames)
        device = next(self.vae.encoder.parameters()).device
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=self.bfloat16):
            return self.vae.encode(frames_to_input(frames.to(device)))[0].float()

    encode = __call__

    @torch.no_grad()
    def decode(self, z) -> np.ndarray:
        """Latents (N, L) -> frames (N, 64, 64, 3) uint8 (the decoder's means)."""
        z = torch.as_tensor(np.asarray(z, np.float32) if not isinstance(z, torch.Tensor) else z).float()
        if z.ndim != 2 or z.shape[-1] != self.latent_size:
            raise ValueError(f"latents must be (N, {self.latent_size}), got {tuple(z.shape)}")
        check_finite("the latents to decode", z)
        device = next(self.vae.encoder.parameters()).device
        return input_to_frames(self.vae.decode(z.to(device))).cpu().numpy()

    def reconstruct(self, frames) -> np.ndarray:
        """Frames (N, 64, 64, 3) uint8 -> their reconstructions from the latent means, same shape."""
        return self.decode(self(frames))


def check_frames(frames) -> torch.Tensor:
    """World Models frames as a uint8 tensor (N, 64, 64, 3); ValueError saying what was expected
    and which environment gives it otherwise."""
    given = frames.dtype if isinstance(frames, torch.Tensor) else np.asarray(frames).dtype
    if not isinstance(frames, torch.Tensor):
        frames = torch.as_tensor(np.asarray(frames))
    if frames.dtype != torch.uint8 or frames.ndim != 4 or tuple(frames.shape[1:]) != (64, 64, 3):
        raise ValueError(f"the vision sees uint8 frames (N, 64, 64, 3), got {given} {tuple(frames.shape)}: "
                         "`agent.env()` (make_env('boxing', preprocessing='world_models')) gives them, one at a time "
                         "(stack them: frames[None] for one)")
    return frames
