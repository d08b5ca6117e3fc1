"""Controller evaluation throughput: a 64 x 5 population on Boxing, vision and memory included.

    python benchmarks/bench_controller.py [--steps 200] [--population 64] [--episodes 5] [--out PATH]

One CMA-ES generation's evaluation (:func:`evaluate_population`) with the thesis sizes: an
untrained VAE (latent 16, encoder as Fig. 44) and MDN-RNN (LSTM 256, 5 Gaussians), a random
linear controller per candidate, P x E = 320 Boxing games stepping at once (ale-py's vector env,
World Models crop and resize). Rows, for 1 and 2 torch threads:

- ``real game``: agent steps/s over ``--steps`` steps of every game (target >= 1,000/s on 2
  cores), and the share of wall time spent in env stepping, preprocessing (crop + resize),
  vision (one batched encode a step), memory (one batched LSTM step), controller (scores +
  argmax) and the rest; with the VAE in float32 and under bfloat16 autocast;
- ``dream``: the same population inside the memory (MDN sampling at temperature 1): model
  steps/s.

Also reported: seconds to start the 320-env vector env (once per training run), and per real-game
row the CPU time per agent step of this process (all threads) with the rate two fully used cores
would give, ``2 / cpu_s_per_step``: a bound that other work on a shared machine does not change.

``OMP_WAIT_POLICY`` defaults to ``PASSIVE`` here (set before torch is imported): with OpenMP's
default, torch's idle threads spin and take the cores from ale-py's stepping threads (measured:
interleaved stepping at ~530 steps/s instead of ~2,300). Export it the same way for training.
Writes ``benchmarks/results/controller.json``.
"""
from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch starts OpenMP (see the docstring)

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.envs.vector import make_game  # noqa: E402
from wmthesis.world_models.controller import num_parameters  # noqa: E402
from wmthesis.world_models.evolution import dream_population, episode_seeds, evaluate_population  # noqa: E402
from wmthesis.world_models.memory import Memory  # noqa: E402
from wmthesis.world_models.vision import VAE, VAEVision  # noqa: E402
from _results import machine_meta, print_table, write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "controller.json"
PARTS = ("env", "preprocess", "vision", "memory", "controller")


def models(latent: int = 16, hidden: int = 256, n_actions: int = 18):
    torch.manual_seed(0)
    return VAE(latent).eval(), Memory(latent, n_actions, hidden_size=hidden).eval()


def real_game_row(game, vision, memory, params, steps: int, threads: int, label: str) -> dict:
    """Agent steps/s of one batched evaluation, with the time split by part."""
    torch.set_num_threads(threads)
    seeds = episode_seeds(0, 0, game.num_envs // len(params))
    evaluate_population(params, game, vision, memory, seeds=seeds, max_steps=5)  # warm-up
    game.timings.clear()
    timings = defaultdict(float)
    start, cpu_start, load = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    _, done_steps = evaluate_population(params, game, vision, memory, seeds=seeds, max_steps=steps,
                                        timings=timings)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    timings.update(game.timings)
    shares = {part: timings[part] / wall for part in PARTS}
    shares["other"] = 1 - sum(shares.values())
    n = int(done_steps.sum())
    return dict(what=f"real game, {label}, threads {threads}", steps_per_s=n / wall, seconds=wall,
                cpu_ms_per_step=1e3 * cpu / n, two_core_bound=2 * n / cpu, load_average_1min=load,
                **{f"share_{k}": v for k, v in shares.items()})


def dream_row(memory, params, episodes: int, steps: int, threads: int) -> dict:
    """Model steps/s of the population dreaming E episodes of ``steps`` steps."""
    torch.set_num_threads(threads)
    memory = copy.deepcopy(memory)
    memory.done.bias.data.fill_(-100.0)  # an untrained done head would end dreams at random
    start_latents = torch.randn(episodes, memory.latent_size)
    generator = torch.Generator().manual_seed(0)
    start = time.perf_counter()
    _, done_steps = dream_population(params, memory, start_latents, max_steps=steps, generator=generator)
    wall = time.perf_counter() - start
    return dict(what=f"dream, threads {threads}", steps_per_s=done_steps.sum() / wall, seconds=wall)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=150, help="steps of every game timed")
    parser.add_argument("--population", type=int, default=64)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)

    vae, memory = models()
    P, E = args.population, args.episodes
    D = num_parameters(vae.latent_size + memory.hidden_size, memory.n_actions)
    params = np.random.default_rng(0).normal(0, 0.1, (P, D))
    start = time.perf_counter()
    game = make_game("boxing", P * E)
    start_seconds = time.perf_counter() - start
    rows = []
    with torch.inference_mode():
        for label, vision in (("VAE float32", VAEVision(vae)), ("VAE bfloat16", VAEVision(vae, bfloat16=True))):
            for threads in (1, 2):
                rows.append(real_game_row(game, vision, memory, params, args.steps, threads, label))
        for threads in (1, 2):
            rows.append(dream_row(memory, params, E, args.steps, threads))
    game.close()

    print(f"controller evaluation, {P} x {E} = {P * E} Boxing games, latent 16, LSTM 256 "
          f"(vector env start: {start_seconds:.1f} s)")
    print_table(rows, ["what", "steps_per_s", "two_core_bound", "load_average_1min",
                       *(f"share_{part}" for part in PARTS + ("other",))])
    meta = machine_meta(population=P, episodes=E, steps=args.steps, latent=16, lstm=256,
                        vector_env_start_s=start_seconds, cpus=os.cpu_count(),
                        omp_wait_policy=os.environ["OMP_WAIT_POLICY"])
    write_results(args.out, meta, rows)


if __name__ == "__main__":
    main()
