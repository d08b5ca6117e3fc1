"""VAE training throughput: the real pipeline (frames sampled from a compressed HDF5 store)
against a bare PyTorch loop on the same batch held in memory. Target: >= 90%.

    python benchmarks/bench_vision.py [--batch 256] [--steps 20] [--out PATH]

Prints a table and writes benchmarks/results/vision.json.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.data import EpisodeStore  # noqa: E402
from wmthesis.rollouts import collect  # noqa: E402
from wmthesis.world_models.vision import VAE, elbo_loss, frames_to_input  # noqa: E402
from _results import machine_meta, print_table, write_results  # noqa: E402


def bare_loop(frames: torch.Tensor, steps: int) -> float:
    """Images/s of VAE updates on one batch kept in memory (the floor of what training costs)."""
    torch.manual_seed(0)
    vae = VAE(16)
    optimiser = torch.optim.Adam(vae.parameters(), lr=1e-3, eps=1e-7)
    x = frames_to_input(frames)
    started = time.perf_counter()
    for _ in range(steps):
        loss = elbo_loss(x, *vae(x))["loss"]
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return steps * len(frames) / (time.perf_counter() - started)


def pipeline(store_path: Path, batch: int, steps: int) -> tuple[float, float]:
    """Images/s of the same updates with every batch sampled from the store, and the share of
    time spent sampling."""
    torch.manual_seed(0)
    vae = VAE(16)
    optimiser = torch.optim.Adam(vae.parameters(), lr=1e-3, eps=1e-7)
    rng = np.random.default_rng(0)
    sampling = 0.0
    with EpisodeStore(store_path) as store:
        started = time.perf_counter()
        for _ in range(steps):
            t = time.perf_counter()
            x = frames_to_input(store.sample_chunks(batch, 1, rng)["observations"][:, 0])
            sampling += time.perf_counter() - t
            loss = elbo_loss(x, *vae(x))["loss"]
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        total = time.perf_counter() - started
    return steps * batch / total, sampling / total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "vision.json")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        store = collect("boxing", 4, Path(tmp) / "boxing.h5", workers=2, seed=0, max_steps=500, progress=False)
        with EpisodeStore(store) as s:
            frames = s.sample_chunks(args.batch, 1, np.random.default_rng(1))["observations"][:, 0]
        bare = bare_loop(frames, args.steps)
        real, sampling_share = pipeline(store, args.batch, args.steps)
    rows = [{"what": "bare PyTorch loop, batch in memory", "images_per_s": bare},
            {"what": "train_vision pipeline, batches from HDF5", "images_per_s": real, "vs_bare": real / bare,
             "sampling_share": sampling_share}]
    print_table(rows)
    write_results(args.out, machine_meta(batch=args.batch, steps=args.steps, torch_threads=torch.get_num_threads()),
                  rows)


if __name__ == "__main__":
    main()
