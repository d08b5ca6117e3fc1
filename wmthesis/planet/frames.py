"""PlaNet's frames and environment (thesis 4.4.4, 5.6.2): every frame resized (the Atari play area
cropped where the config says) and reduced to ``bits`` bits, the game stepped with the config's
action repeat."""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from wmthesis.envs import ATARI_GAMES, make_env
from wmthesis.envs.preprocessing import CROPS, crop_resize, quantize
from wmthesis.planet.config import PlaNetConfig

FRAME_SIZE = 64


def make_planet_env(env_name: str, config: PlaNetConfig) -> gym.Env:
    """The environment with PlaNet's settings and frames (:class:`PlanetFrames`): Atari with
    the config's action repeat; ``max_episode_steps`` truncates episodes."""
    options = {} if config.max_episode_steps is None else {"max_steps": config.max_episode_steps}
    crop = None
    if env_name in ATARI_GAMES:
        options["action_repeat"] = config.action_repeat
        crop = CROPS[ATARI_GAMES[env_name]] if config.crop else None
    return PlanetFrames(make_env(env_name, **options), config.frame_size, config.bits, crop)


class PlanetFrames(gym.ObservationWrapper):
    """Observations as the RSSM sees them: :func:`planet_frame` of every frame,
    (size, size, 3) uint8 with ``bits`` bits."""

    def __init__(self, env: gym.Env, size: int = FRAME_SIZE, bits: int = 5, crop=None):
        super().__init__(env)
        self.size, self.bits, self.crop = size, bits, crop
        self.observation_space = gym.spaces.Box(0, 255, (size, size, 3), np.uint8)

    def observation(self, frame: np.ndarray) -> np.ndarray:
        return planet_frame(frame, self.bits, self.size, self.crop)


def planet_frame(frame: np.ndarray, bits: int = 5, size: int = FRAME_SIZE,
                 crop: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Any (H, W, 3) uint8 frame -> (size, size, 3) with ``bits`` bits: the whole frame (or
    ``frame[top:bottom, left:right]`` for a ``crop``) resized by area, then quantised."""
    if crop is not None or frame.shape[:2] != (size, size):
        frame = crop_resize(frame, crop, size)
    return quantize(frame, bits)


__all__ = ["FRAME_SIZE", "make_planet_env", "PlanetFrames", "planet_frame"]
