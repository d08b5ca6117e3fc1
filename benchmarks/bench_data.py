"""Data pipeline throughput: Atari stepping, collection into HDF5, chunk sampling.

    python benchmarks/bench_data.py [--seconds 5] [--episodes 8] [--batches 50] [--out PATH]

Rows (Boxing, frame skip 4, sticky actions off, random actions):

- ``ale-py env``: one ``ALE/Boxing-v5`` gymnasium env, raw frames: agent steps/s;
- ``AtariVectorEnv``: ale-py's vector env, 16 envs, 2 threads, 64x64 RGB frames: agent
  steps/s, the reference rate for collection;
- ``collect, K workers``: :func:`wmthesis.rollouts.collect` of full-length episodes (random
  actions, every reset seeded) with ``world_models`` preprocessing into a fresh HDF5 store:
  steps/s and the ratio to the vector env's rate (target >= 70%). ``wall``: `--episodes` per
  worker, process start-up (~3 s for spawned workers importing torch) included; ``steady``:
  the marginal rate between that run and one of twice as many episodes;
- ``sample_chunks``: one batch of 50 chunks of 50 steps of 64x64x3 frames drawn from the
  2-worker store (real Boxing frames, LZ4-compressed): median and 90th percentile ms over
  `--batches` batches (target <= 20 ms), and the file size per 1000 frames.

Each rate is given twice: per wall second, and per CPU second times the cores the work keeps
busy (``CPU steps/s``: 1 for one env or one worker, 2 for the vector env's 2 threads or 2
workers; CPU time counts this process's threads and collect's workers, the parent's writing
included). On an idle 2-core machine the two agree; on a shared machine the CPU rate still
measures the code, not the neighbours' load. Sampling likewise reports CPU ms.

Writes ``benchmarks/results/data.json``.
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.data import EpisodeStore  # noqa: E402
from wmthesis.rollouts import collect  # noqa: E402
from _results import machine_meta, print_table, write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "data.json"
VECTOR_ENVS, VECTOR_THREADS = 16, 2
CHUNK_BATCH, CHUNK_LENGTH = 50, 50
CORES = 2  # the machines this project targets
COLUMNS = ("what", "steps_per_s", "vs_vector_env", "cpu_steps_per_s", "cpu_vs_vector_env", "median_ms", "p90_ms",
           "cpu_median_ms", "mb_per_1000_frames")


class Clock:
    """Wall and CPU seconds since creation; CPU counts this process's threads and its reaped
    children (collect's workers), so ``steps / cpu`` does not depend on other users' load."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), _cpu()

    def seconds(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall, _cpu() - self.cpu


def _cpu() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def machine_busy() -> tuple[float, float] | None:
    """(busy, total) CPU seconds of the whole machine so far (Linux ``/proc/stat``), else None."""
    try:
        ticks = [int(n) for n in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
    except (OSError, ValueError):
        return None
    hertz = os.sysconf("SC_CLK_TCK")
    return (sum(ticks) - ticks[3] - ticks[4]) / hertz, sum(ticks) / hertz


def others_share(before, after, own_cpu: float) -> float | None:
    """Share of the machine's CPU that other processes used between two :func:`machine_busy`."""
    if before is None or after is None:
        return None
    return max(0.0, (after[0] - before[0] - own_cpu) / (after[1] - before[1]))


def rates(steps: int, wall: float, cpu: float, cores: int) -> dict:
    """Steps per wall second, and per CPU second times the `cores` the work keeps busy (its
    rate on an idle machine)."""
    return dict(steps_per_s=steps / wall, cpu_steps_per_s=cores * steps / cpu)


def ale_env_rate(seconds: float) -> dict:
    """Agent steps/s of one raw ``ALE/Boxing-v5`` env with random actions (one core)."""
    import ale_py
    import gymnasium as gym

    gym.register_envs(ale_py)
    env = gym.make("ALE/Boxing-v5", frameskip=4, repeat_action_probability=0.0)
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, env.action_space.n, 1_000_000)
    steps, clock = 0, Clock()
    while clock.seconds()[0] < seconds:
        _, _, terminated, truncated, _ = env.step(actions[steps])
        steps += 1
        if terminated or truncated:
            env.reset()
    return rates(steps, *clock.seconds(), cores=1)


def vector_env_rate(seconds: float) -> dict:
    """Agent steps/s of ale-py's ``AtariVectorEnv``: 16 Boxing envs, 2 threads, 64x64 RGB."""
    from ale_py.vector_env import AtariVectorEnv

    env = AtariVectorEnv("boxing", VECTOR_ENVS, num_threads=VECTOR_THREADS, img_height=64,
                         img_width=64, grayscale=False, stack_num=1, frameskip=4,
                         repeat_action_probability=0.0, noop_max=0, reward_clipping=False)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    steps, clock = 0, Clock()
    while clock.seconds()[0] < seconds:
        env.step(rng.integers(0, 18, VECTOR_ENVS))
        steps += VECTOR_ENVS
    result = rates(steps, *clock.seconds(), cores=VECTOR_THREADS)
    env.close()
    return result


def collect_rates(directory: Path, episodes: int, workers: int) -> tuple[dict, dict, Path]:
    """Rates of collecting full Boxing episodes into fresh stores with `workers`.

    Returns the rates of `episodes` episodes (process start-up included), the steady rates
    (the marginal rate between that run and one of twice the episodes: start-up cancels out)
    and the larger store's path.
    """
    runs = []
    for count in (episodes, 2 * episodes):
        path = directory / f"collect{workers}x{count}.h5"
        clock = Clock()
        collect("boxing", count, path, workers=workers, progress=False)
        with EpisodeStore(path) as store:
            runs.append((store.num_steps, *clock.seconds()))
    (steps, wall, cpu), (more_steps, more_wall, more_cpu) = runs
    cores = min(workers, CORES)
    return (rates(steps, wall, cpu, cores),
            rates(more_steps - steps, more_wall - wall, more_cpu - cpu, cores), path)


def chunk_sampling(path: Path, batches: int) -> dict:
    """Milliseconds (wall and CPU) per 50x50 batch of chunks; file size per 1000 frames."""
    rng = np.random.default_rng(0)
    with EpisodeStore(path) as store:
        store.sample_chunks(CHUNK_BATCH, CHUNK_LENGTH, rng)  # warm-up
        walls, cpus = [], []
        for _ in range(batches):
            clock = Clock()
            store.sample_chunks(CHUNK_BATCH, CHUNK_LENGTH, rng)
            wall, cpu = clock.seconds()
            walls.append(wall)
            cpus.append(cpu)
        frames = store.num_steps
    return dict(median_ms=1e3 * float(np.median(walls)), p90_ms=1e3 * float(np.percentile(walls, 90)),
                cpu_median_ms=1e3 * float(np.median(cpus)), frames=frames,
                mb_per_1000_frames=path.stat().st_size / frames * 1000 / 2**20)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="per stepping measurement")
    parser.add_argument("--episodes", type=int, default=8,
                        help="full episodes per collect worker (and twice that for the steady rate)")
    parser.add_argument("--batches", type=int, default=50, help="chunk batches timed")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)

    busy_before, clock = machine_busy(), Clock()
    rows = [dict(what="ale-py env (raw frames), 1 core", **ale_env_rate(args.seconds))]
    reference = vector_env_rate(args.seconds)
    vector = f"AtariVectorEnv {VECTOR_ENVS} envs, {VECTOR_THREADS} threads, 64x64 RGB"
    rows.append(dict(what=vector, **reference))
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            wall, steady, path = collect_rates(Path(tmp), args.episodes * workers, workers)
            name = f"collect world_models -> HDF5, {workers} worker{'s' if workers > 1 else ''}"
            rows.append(dict(what=f"{name}, wall", **wall))
            rows.append(dict(what=f"{name}, steady", **steady))
        sampling = chunk_sampling(path, args.batches)
    rows.append(dict(what=f"sample_chunks {CHUNK_BATCH}x{CHUNK_LENGTH} of 64x64x3", **sampling))
    for row in rows[2:-1]:
        row["vs_vector_env"] = row["steps_per_s"] / reference["steps_per_s"]
        row["cpu_vs_vector_env"] = row["cpu_steps_per_s"] / reference["cpu_steps_per_s"]
    print_table(rows, COLUMNS)
    others = others_share(busy_before, machine_busy(), clock.seconds()[1])
    if others is not None:
        print(f"other processes used {others:.0%} of the machine's CPU meanwhile "
              f"(wall rates are lowered by that much; CPU rates are not)")

    meta = machine_meta(episodes_per_worker=args.episodes, seconds=args.seconds, batches=args.batches,
                        others_cpu_share=others)
    write_results(args.out, meta, rows)


if __name__ == "__main__":
    main()
