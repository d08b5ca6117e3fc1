"""Configs as dataclasses with the thesis defaults written once, and the three profiles.

A config's defaults ARE the thesis's values (the `thesis` profile). The `smoke` and `quick`
profiles override a few fields:

- ``smoke``: seconds per step; proves the plumbing in CI.
- ``quick``: a 2-core CPU in under an hour per experiment, with meaningful results.
- ``thesis``: the thesis's hyperparameters exactly; meant for a GPU.

    >>> cfg = for_profile(CollectConfig, "smoke")
    >>> cfg.episodes
    4

Notebooks pick the profile in their parameters cell with :func:`profile_name`, which reads
``WMTHESIS_PROFILE`` when it is set.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from wmthesis.utils import check_choice

PROFILES = ("smoke", "quick", "thesis")
DEFAULT_PROFILE = "quick"


@dataclass(frozen=True)
class CollectConfig:
    """Random-rollout collection (thesis 4.2.3: 10,000 random rollouts)."""

    episodes: int = 10_000
    max_steps: int | None = None  # None: full-length episodes
    workers: int = 2


@dataclass(frozen=True)
class VisionConfig:
    """Thesis defaults: latent 16, Adam lr 1e-3, eps 1e-7, batch 256."""

    latent_size: int = 16
    lr: float = 1e-3
    adam_eps: float = 1e-7
    batch_size: int = 256


@dataclass(frozen=True)
class MemoryConfig:
    """Thesis defaults: LSTM 256, 5 Gaussians, Adam lr 1e-3, eps 1e-8, batch 128 x 1000 steps."""

    kind: str = "mdn"
    hidden_size: int = 256
    n_gaussians: int = 5
    auxiliary: bool = False
    temperature: float = 1.0
    lr: float = 1e-3
    adam_eps: float = 1e-8
    batch_size: int = 128
    sequence_length: int = 1000


# Per profile, per config class name: the fields that differ from the thesis defaults.
OVERRIDES: dict[str, dict[str, dict]] = {
    "smoke": {
        "CollectConfig": dict(episodes=4, max_steps=50, workers=1),
    },
    "quick": {
        "CollectConfig": dict(episodes=20),
    },
    "thesis": {},
}


def profile_name(name: str | None = None) -> str:
    """The profile to use: `name` if given, else ``$WMTHESIS_PROFILE``, else ``quick``."""
    name = name or os.environ.get("WMTHESIS_PROFILE") or DEFAULT_PROFILE
    check_choice("profile", name, PROFILES)
    return name


def for_profile(cls, profile: str | None = None, **changes):
    """An instance of config class `cls` for `profile`, with explicit `changes` on top."""
    profile = profile_name(profile)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = set(changes) - fields
    if unknown:
        raise TypeError(f"{cls.__name__} has no field(s) {sorted(unknown)}; valid: {sorted(fields)}")
    values = {**OVERRIDES[profile].get(cls.__name__, {}), **changes}
    return cls(**values)
