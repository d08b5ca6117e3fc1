"""Small helpers shared by every module: device choice, seeding, atomic file writes."""
from __future__ import annotations

import os
import random
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch


def device() -> torch.device:
    """CUDA when present, the CPU otherwise."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def seed_everything(seed: int) -> np.random.Generator:
    """Seed Python, NumPy and torch; return a fresh NumPy generator for explicit use."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return np.random.default_rng(seed)


@contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to `path`; move it into place only if the block succeeds.

    A crash mid-write leaves the previous file (if any) untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def read_pickle(path: str | os.PathLike):
    """The object pickled at `path`; a truncated or corrupt file raises a ValueError that names
    it (files written through :func:`atomic_path` are whole unless copied or edited by hand)."""
    import pickle

    with open(path, "rb") as f:
        try:
            return pickle.load(f)
        except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError) as error:
            raise ValueError(f"{path} is truncated or corrupt ({type(error).__name__}: {error}); "
                             "delete it to start that step again") from error


def check_choice(kind: str, value, valid) -> None:
    """Fail at once, listing the valid choices, when `value` is not one of them."""
    if value not in valid:
        raise ValueError(f"unknown {kind} {value!r}; valid: {', '.join(map(str, valid))}")


def data_dir(*parts: str) -> Path:
    """Where run-time artifacts go: ``$WMTHESIS_DATA`` if set, else the checkout's ``data/``.

    Extra ``parts`` are joined on and the folder is created.
    """
    root = os.environ.get("WMTHESIS_DATA")
    if root is None:
        checkout = Path(__file__).resolve().parents[1]
        root = checkout / "data" if (checkout / "pyproject.toml").exists() else Path.cwd() / "data"
    path = Path(root, *parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def derive_seeds(*keys: int, n: int = 1) -> np.ndarray:
    """``n`` well-mixed uint32 seeds derived from integer ``keys`` (e.g. a base seed and an
    episode index) with NumPy's SeedSequence: the one way every module derives seeds."""
    return np.random.SeedSequence(list(keys)).generate_state(n)
