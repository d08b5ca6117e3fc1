"""A discrete state learned from pixels (thesis 5.3.1's input): one of K codes per cell.

The thesis's VAE squeezed a Sokoban frame into 16 continuous numbers and its memory lost the
player; a board is a grid of tiles, so here each tile gets a categorical latent ("a
natural choice, not a rule"). :class:`CellCoder` is a vector quantiser over tile-sized patches:
a codebook of ``n_codes`` patches fit by k-means (OpenCV's, k-means++ starts) to the patches of
random play's frames; a patch's code is its nearest codebook entry, and a code decodes to its
entry. Nothing says which code means what.

A neural autoencoder with a categorical code per cell (straight-through Gumbel-softmax) was
tried first and collapsed onto 1-4 codes for 7 tile types (its encoder's logits saturate within
50 updates); k-means finds every tile type, and reconstructs the frames exactly.

Frames: the env's RGB observations (``SokobanEnv(observation="rgb", tile_size=t)``) with the
outer ring of tiles (always wall) cropped, as World Models crops the border (4.2.4): uint8
(B, h * t, w * t, 3) for a board's (h, w) inner cells.
"""
from __future__ import annotations

import cv2
import numpy as np

from wmthesis.envs.sokoban import CELL_NAMES, make_tiles


class CellCoder:
    """``encode(frames uint8 (B, h*t, w*t, 3)) -> codes uint8 (B, h, w)``; ``decode`` back.

    ``codebook``: float32 (K, t * t * 3), one patch per code.
    """

    def __init__(self, codebook: np.ndarray, tile_size: int):
        self.codebook, self.tile_size = np.asarray(codebook, np.float32), int(tile_size)
        self.n_codes = len(self.codebook)

    def patches(self, frames: np.ndarray) -> np.ndarray:
        """(B, h*t, w*t, 3) -> (B, h, w, t*t*3)."""
        frames = np.asarray(frames)
        b, height, width, _ = frames.shape
        t = self.tile_size
        if height % t or width % t:
            raise ValueError(f"frames of {height}x{width} pixels are not whole tiles of {t}x{t}")
        h, w = height // t, width // t
        return frames.reshape(b, h, t, w, t, 3).transpose(0, 1, 3, 2, 4, 5).reshape(b, h, w, t * t * 3)

    def encode(self, frames: np.ndarray) -> np.ndarray:
        x = self.patches(frames).astype(np.float32)
        distances = (x ** 2).sum(-1, keepdims=True) - 2 * x @ self.codebook.T + (self.codebook ** 2).sum(-1)
        return distances.argmin(-1).astype(np.uint8)

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """Codes (B, h, w) -> frames uint8 (B, h*t, w*t, 3)."""
        b, h, w = np.shape(codes)
        t = self.tile_size
        patches = np.clip(np.rint(self.codebook[np.asarray(codes)]), 0, 255).astype(np.uint8)
        return patches.reshape(b, h, w, t, t, 3).transpose(0, 1, 3, 2, 4, 5).reshape(b, h * t, w * t, 3)

    def state(self) -> dict:
        return {"codebook": self.codebook, "tile_size": self.tile_size}


def fit_coder(frames, tile_size: int = 8, n_codes: int = 8, seed: int = 0) -> CellCoder:
    """A codebook of ``n_codes`` patches fit by k-means to the patches of ``frames`` (an array
    (B, H, W, 3), or a list of them: boards of several sizes)."""
    blank = CellCoder(np.zeros((1, 1)), tile_size)
    frames = [frames] if isinstance(frames, np.ndarray) else list(frames)
    patches = np.concatenate([blank.patches(f).reshape(-1, tile_size * tile_size * 3) for f in frames])
    cv2.setRNGSeed(int(seed))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    _, _, centres = cv2.kmeans(patches.astype(np.float32), n_codes, None, criteria, 3, cv2.KMEANS_PP_CENTERS)
    return CellCoder(centres, tile_size)


def render_cells(states: np.ndarray, tile_size: int = 8) -> np.ndarray:
    """Grid observations (B, h, w) -> the env's RGB frames of those cells, uint8
    (B, h*t, w*t, 3): the observation ``SokobanEnv(observation="rgb", tile_size=t)`` shows,
    outer ring cropped (the same sprites; a test checks they are equal)."""
    tiles = make_tiles(tile_size)
    b, h, w = states.shape
    t = tile_size
    return tiles[states].transpose(0, 1, 3, 2, 4, 5).reshape(b, h * t, w * t, 3)


def crop_ring(observation: np.ndarray, tile_size: int) -> np.ndarray:
    """An RGB observation (H, W, 3) without its outer ring of tiles."""
    return observation[tile_size:-tile_size, tile_size:-tile_size]


def code_table(codes: np.ndarray, states: np.ndarray, n_codes: int | None = None, n_types: int = 7) -> np.ndarray:
    """For each code, the cell type it most often stands for (-1: never seen): (n_codes,) from
    codes and the true grid states of the same frames (used to measure, never by the agent)."""
    table = np.full(max(int(codes.max()) + 1, n_codes or 0), -1)
    for code in np.unique(codes):
        table[code] = np.bincount(states[codes == code], minlength=n_types).argmax()
    return table


# ---------------------------------------------------------------------------- what the agent sees

class GridInputs:
    """The agent sees grid states (5.3.2): the env's ``grid`` observation, the board's inner cells."""

    name = "grid"
    env_options = {"observation": "grid"}

    def observe(self, env, observation: np.ndarray) -> np.ndarray:
        """An observation -> the model's state, uint8 (h', w')."""
        h, w = env.dim_room
        return np.asarray(observation, np.uint8).reshape(h - 2, w - 2)

    def from_grid(self, states: np.ndarray) -> np.ndarray:
        """Stored grid observations (B, h', w') -> model states (B, h', w')."""
        return np.asarray(states, np.uint8)

    def type_codes(self) -> np.ndarray:
        """(T,) the model state's code of each cell type (:data:`~wmthesis.envs.sokoban.CELL_NAMES`):
        what the true rules need to act on this input (:class:`~wmthesis.sokoban_search.search.Simulator`)."""
        return self.from_grid(np.arange(len(CELL_NAMES), dtype=np.uint8)[None, None])[0, 0]


FRAMES_AT_ONCE = 4096  # boards rendered and coded together: a 0.45 GB peak for Boxoban's (bench_sokoban_search)


class PixelInputs(GridInputs):
    """The agent sees pixels (5.3.1): RGB frames, the outer ring cropped, one code per cell."""

    name = "pixels"

    def __init__(self, coder: CellCoder):
        self.coder = coder
        self.env_options = {"observation": "rgb", "tile_size": coder.tile_size}

    def observe(self, env, observation: np.ndarray) -> np.ndarray:
        return self.coder.encode(crop_ring(observation, self.coder.tile_size)[None])[0]

    def from_grid(self, states: np.ndarray) -> np.ndarray:
        """Grid observations (B, h, w) -> the codes of their frames (the env's exact rendering),
        :data:`FRAMES_AT_ONCE` boards at a time: all of random play's frames at once took 12 GB."""
        states = np.asarray(states)
        return np.concatenate([self.coder.encode(render_cells(states[i:i + FRAMES_AT_ONCE], self.coder.tile_size))
                               for i in range(0, max(len(states), 1), FRAMES_AT_ONCE)])


GRID = GridInputs()


__all__ = ["CellCoder", "fit_coder", "render_cells", "crop_ring", "code_table", "GridInputs", "PixelInputs", "GRID"]
