"""The RSSM's convolutional encoder and decoder for any square frame size (thesis 4.4.1).

At the thesis's size, 64x64 frames and depth 32, :func:`vision_networks` returns PlaNet's own
networks, which are the World Models VAE's (:mod:`wmthesis.world_models.vision`): four 4x4
stride-2 convolutions of 32, 64, 128, 256 channels (embedding 1024) and the matching
transposed convolutions. Other sizes (the ``quick`` profile's 32x32 frames of depth 16) get the
same shape of network with padding 1, so that every layer halves (or doubles) the frame
exactly::

    encoder: (N, 3, S, S) -> conv 4x4/2 x L (depth, 2 depth, ..., 2^(L-1) depth) -> (N, E)
    decoder: (N, F) -> FC -> (N, 2^(L-1) depth, 2, 2) -> transposed conv 4x4/2 x L -> (N, 3, S, S)

with ``L = log2(S) - 1`` layers and ``E = 4 * 2^(L-1) * depth``.
"""
from __future__ import annotations

import math

from torch import nn

from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.rssm import RSSM
from wmthesis.utils import device

THESIS_SIZE, THESIS_DEPTH = 64, 32


def vision_networks(frame_size: int, depth: int, features: int) -> tuple[nn.Module, nn.Module, int]:
    """``(encoder, decoder, embedding_size)`` for (N, 3, frame_size, frame_size) frames;
    the decoder maps (N, ``features``) -> frames."""
    layers = math.log2(frame_size) - 1
    if frame_size < 4 or layers != int(layers) or depth < 1:
        raise ValueError(f"frame_size must be a power of two >= 4 and depth >= 1, got {frame_size}, {depth}")
    if (frame_size, depth) == (THESIS_SIZE, THESIS_DEPTH):
        from wmthesis.world_models.vision import Decoder, Encoder

        return Encoder(), Decoder(features), 1024
    widths = [depth * 2 ** i for i in range(int(layers))]
    return HalvingEncoder(widths), DoublingDecoder(widths, features), 4 * widths[-1]


class HalvingEncoder(nn.Module):
    """(N, 3, S, S) -> (N, 4 * widths[-1]): one 4x4 stride-2 convolution (padding 1, ReLU)
    per width, from S down to 2."""

    def __init__(self, widths: list[int]):
        super().__init__()
        self.frame_size = 2 ** (len(widths) + 1)
        layers, channels = [], 3
        for width in widths:
            layers += [nn.Conv2d(channels, width, 4, stride=2, padding=1), nn.ReLU()]
            channels = width
        self.net = nn.Sequential(*layers, nn.Flatten())

    def forward(self, x):
        return self.net(x)


class DoublingDecoder(nn.Module):
    """(N, F) -> (N, 3, S, S): a linear layer to (widths[-1], 2, 2), then one 4x4 stride-2
    transposed convolution per width (ReLU between), the last to 3 channels."""

    def __init__(self, widths: list[int], features: int):
        super().__init__()
        self.top = widths[-1]
        self.fc = nn.Linear(features, 4 * self.top)
        layers, outs = [], [*widths[-2::-1], 3]
        channels = self.top
        for i, width in enumerate(outs):
            layers.append(nn.ConvTranspose2d(channels, width, 4, stride=2, padding=1))
            if i < len(outs) - 1:
                layers.append(nn.ReLU())
            channels = width
        self.net = nn.Sequential(*layers)

    def forward(self, features):
        return self.net(self.fc(features).view(-1, self.top, 2, 2))


def build_model(config: PlaNetConfig, n_actions: int) -> RSSM:
    """An RSSM of the config's sizes on :func:`wmthesis.utils.device`."""
    encoder, decoder, embedding = vision_networks(config.frame_size, config.depth,
                                                  config.belief_size + config.state_size)
    return RSSM(n_actions, config.belief_size, config.state_size, config.hidden_size,
                config.reward_hidden_size, config.min_std, encoder=encoder, decoder=decoder,
                embedding_size=embedding).to(device())


__all__ = ["build_model", "vision_networks", "HalvingEncoder", "DoublingDecoder"]
