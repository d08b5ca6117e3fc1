"""Seeds of experiments as Ray tasks: ``python -m wmthesis sweep EXPERIMENT[:VARIANT] ... --seeds 0-4``.

Each ``(experiment, variant, seed)`` is one task: :func:`~wmthesis.experiments.reproduce` in a
Ray worker, asking for ``cpus`` CPUs (its torch threads) and a GPU where the cluster has one.
By default the sweep starts a Ray of its own on this machine; ``address`` joins a cluster
(``"auto"``, ``"HOST:6379"`` or ``"ray://HOST:10001"``).

Runs are independent and resumable: a run whose worker dies is retried (``retries`` times) and
resumes from its checkpoints (every experiment skips the work whose artifact exists); a run that
raises is reported with its error while the others go on. The driver writes each run's
``metrics.json`` into its own ``data/results/`` as the run returns, so the summary needs no
shared filesystem; to resume a run on another node, the data folder must be on shared storage.
A run whose ``metrics.json`` is already there is not run again, so re-running a sweep (after
Ctrl-C, which stops the workers) runs only what is missing. A run's prerequisite in the same
sweep (``boxing-wm`` for ``boxing-wm-alphazero``, ``planet-boxing-agent`` for
``planet-boxing-value``, same seed) finishes before it starts, as both write the same folders.
"""
from __future__ import annotations

import json
import os
import re
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Callable, NamedTuple

from tqdm import tqdm

from wmthesis.config import profile_name
from wmthesis.declarations import DECLARED, NO_SCORE
from wmthesis.experiments import DEFAULT_RESULTS, EXPERIMENTS, VARIANTS, reproduce
from wmthesis.runs import atomic_path
from wmthesis.summary import run_scores
from wmthesis.utils import MAX_SEED, MAX_SEEDS, check_choice, data_dir, masked, parse_seeds, process_alive



def depth(experiment: str) -> int:
    """How many experiments deep ``experiment`` builds (0: on none): a sweep starts the shallow first."""
    builds_on = DECLARED[experiment].builds_on
    return 1 + max(map(depth, builds_on)) if builds_on else 0


class SweepRun(NamedTuple):
    """One task of a sweep: an experiment, its variant (None: its default, or it has none) and a seed."""
    experiment: str
    variant: str | None
    seed: int

    def __str__(self) -> str:
        return f"{self.experiment}{':' + self.variant if self.variant else ''} seed {self.seed}"


def variants_of(experiment: str) -> tuple[str, ...]:
    """The variants ``experiment`` accepts (empty: it has none)."""
    check_choice("experiment", experiment, EXPERIMENTS)
    return tuple(VARIANTS.get(experiment, ()))


def parse_runs(specs: list[str], seeds: list[int]) -> list[SweepRun]:
    """``EXPERIMENT[:VARIANT]`` specs x seeds -> the sweep's runs; an unknown experiment or
    variant raises ValueError listing the valid ones."""
    runs = []
    for spec in specs:
        experiment, _, variant = spec.partition(":")
        if variant:
            if not variants_of(experiment):
                raise ValueError(f"experiment {experiment!r} has no variants, got {variant!r}")
            VARIANTS[experiment].check(variant)
        check_choice("experiment", experiment, EXPERIMENTS)
        runs.extend(SweepRun(experiment, variant or None, seed) for seed in seeds)
    return list(dict.fromkeys(runs))


def finished(run: SweepRun, profile: str, folder: Path | None = None) -> Path | None:
    """The ``metrics.json`` under ``folder`` (default ``data/results/EXPERIMENT``) that holds
    ``run`` in ``profile``, or None."""
    wanted = _wanted_variants(run)
    folder = folder or data_dir("results", run.experiment)
    for path in folder.rglob("metrics.json"):
        try:
            metrics = json.loads(path.read_text())
            if (metrics["experiment"], metrics["profile"], metrics["seed"]) == (run.experiment, profile, run.seed) \
                    and wanted <= set(run_scores(metrics)):
                return path
        except (ValueError, KeyError, TypeError, OSError):
            continue
    return None


def _wanted_variants(run: SweepRun) -> set:
    """The variants a finished run's metrics must hold: the named one, else the default run's."""

    if run.variant is not None:
        return {run.variant}
    if run.experiment in DEFAULT_RESULTS:
        return {DEFAULT_RESULTS[run.experiment]}
    return set() if DECLARED[run.experiment].score == NO_SCORE else {None}


DRIVER_CHECK_S = 2.0  # how often a worker on the driver's machine looks whether the driver still runs
_WATCHED: set[int] = set()  # the drivers this worker process watches


def end_with_driver(driver: tuple[str, int], every: float = DRIVER_CHECK_S) -> None:
    """In a worker on the driver's machine (``driver``: its host name and process id): a daemon
    thread that ends this process once the driver is gone, so a killed sweep leaves no run going
    on (each resumes from its checkpoints when the sweep runs again)."""
    host, pid = driver
    if socket.gethostname() != host or pid in _WATCHED:  # a worker runs many tasks: one watch a driver
        return
    _WATCHED.add(pid)

    def watch() -> None:
        while process_alive(pid):
            time.sleep(every)
        os._exit(1)

    threading.Thread(target=watch, name="end-with-driver", daemon=True).start()


def _run_task(runner: Callable, run: SweepRun, profile: str, threads: int, driver: tuple[str, int],
              *prerequisites) -> tuple[dict, str]:
    """In a Ray worker: one run with ``threads`` torch threads, after its ``prerequisites``
    (results of other tasks, which Ray waits for before it calls), ended with its ``driver``
    (:func:`end_with_driver`); returns its metrics and the path of its ``metrics.json``
    relative to the worker's data folder."""
    end_with_driver(driver)
    import matplotlib

    matplotlib.use("Agg")
    import torch

    torch.set_num_threads(threads)
    metrics = runner(run.experiment, profile, run.seed, variant=run.variant, progress=False)
    path = finished(run, profile)
    return metrics, str(path.relative_to(data_dir())) if path else ""


def check_address(address: str, timeout: float = 5.0) -> None:
    """Fail at once, with one line, when ``address`` (``HOST:PORT`` or ``ray://HOST:PORT``) does
    not answer; ``"auto"`` and ``"local"`` are left to Ray."""
    if address in ("auto", "local"):
        return
    match = re.fullmatch(r"(?:ray://)?\[?([^\]/]+?)\]?:(\d+)/?", address)
    if match is None:
        raise ValueError(f"--address {masked(address)!r}: expected auto, HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((match[1], int(match[2])), timeout=timeout).close()
    except OSError as error:
        raise ValueError(f"--address {masked(address)!r}: no Ray cluster answers there ({error})") from None


JOIN_TIMEOUT_S = 30.0


def check_joinable(address: str, timeout: float = JOIN_TIMEOUT_S) -> None:
    """Fail within ``timeout`` seconds, with one line naming ``address``, when a Ray driver cannot
    join the cluster there (tried in a child process: a port that answers but is no joinable Ray
    leaves ``ray.init`` retrying for minutes, printing a warning every few seconds)."""
    import subprocess

    probe = f"import ray; ray.init(address={masked(address)!r}, log_to_driver=False); ray.shutdown()"
    try:
        done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ValueError(f"--address {masked(address)!r}: no Ray cluster could be joined there within {timeout:.0f} s") from None
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise ValueError(f"--address {masked(address)!r}: no Ray cluster could be joined there ({last})")


class RayStartFailed(RuntimeError):
    """A Ray of this machine's own did not start (on a busy machine its processes can miss
    Ray's startup deadlines)."""


def start_ray(address: str | None, cpus: int | None = None, attempts: int = 3, wait_s: float = 10.0) -> bool:
    """Join the cluster at ``address``, or start a Ray of this machine's own (``address`` None,
    its workers writing to this process's data folder; ``attempts`` tries ``wait_s`` apart, each
    failed start shut down before the next). Returns whether Ray was started here (False: this
    process had joined one already); :class:`RayStartFailed` when no attempt started."""
    import ray

    if ray.is_initialized():
        return False
    if address is None:
        os.environ["WMTHESIS_DATA"] = str(data_dir())  # the local workers inherit the environment
        for attempt in range(1, attempts + 1):
            try:
                ray.init(address="local", num_cpus=cpus or os.cpu_count(), include_dashboard=False, log_to_driver=False)
                return True
            except Exception as error:  # Ray raises a bare Exception when its node misses the startup deadline
                ray.shutdown()
                if attempt == attempts:
                    raise RayStartFailed(f"a local Ray did not start in {attempts} attempts ({error}); on a busy "
                                         "machine wait for the load to drop and run the sweep again (finished runs "
                                         "are kept), or run one seed with `reproduce`") from None
                print(f"a local Ray did not start ({error}); trying again in {wait_s:.0f} s", file=sys.stderr)
                time.sleep(wait_s)
    else:
        check_address(address)
        check_joinable(address, JOIN_TIMEOUT_S)
        try:
            ray.init(address=address, log_to_driver=False)
        except ConnectionError as error:
            raise ValueError(f"--address {masked(address)!r}: {error}") from None
    return True


def sweep(runs: list[SweepRun], profile: str | None = None, address: str | None = None, cpus: int = 1,
          gpus: float | None = None, retries: int = 3, runner: Callable | None = None,
          progress: bool = True) -> dict[SweepRun, dict]:
    """Run every run of ``runs`` not finished yet as a Ray task; return each run's outcome:
    ``{"status": "done" | "finished before" | "failed", "path", "wall_seconds" | "error"}``.

    ``cpus`` per run (its torch threads); ``gpus`` per run (default: 1 where the cluster has a
    GPU, else 0); ``retries``: how often a run whose worker died starts again; ``runner``:
    what a task calls (default :func:`~wmthesis.experiments.reproduce`). Ctrl-C cancels the
    runs under way (the finished ones are kept) and re-raises KeyboardInterrupt.
    """
    import ray

    profile = profile_name(profile)
    runner = runner or reproduce
    outcome = {run: {"status": "finished before", "path": str(path)}
               for run in runs if (path := finished(run, profile)) is not None}
    todo = sorted((run for run in runs if run not in outcome), key=lambda run: depth(run.experiment))
    if not todo:
        return outcome
    ours = start_ray(address)
    if gpus is None:
        gpus = 1 if ray.cluster_resources().get("GPU", 0) >= 1 else 0
    task = ray.remote(_run_task).options(num_cpus=cpus, num_gpus=gpus, max_retries=retries, retry_exceptions=False)
    refs, started = {}, time.time()
    for run in todo:  # a prerequisite in this sweep goes first: its result is the dependent's argument;
        # variants of a dependent experiment and seed share its prerequisite's folders, so they go one by one
        builds_on = DECLARED[run.experiment].builds_on
        before = [refs[p] for p in refs if p.seed == run.seed and (p.experiment in builds_on or
                                                                   (p.experiment == run.experiment and bool(builds_on)))]
        refs[run] = task.remote(runner, run, profile, cpus, (socket.gethostname(), os.getpid()), *before)
    waiting = {ref: run for run, ref in refs.items()}
    bar = tqdm(total=len(todo), desc=f"sweep ({profile})", unit="run", disable=not progress)
    try:
        while waiting:  # waits of a second: back in Python between them, where a Ctrl-C is raised
            ready, _ = ray.wait(list(waiting), num_returns=1, timeout=1.0)  # (Ray's own wait may hold it back)
            if not ready:
                continue
            run = waiting.pop(ready[0])
            outcome[run] = _collect(ray, ready[0], run, started)
            bar.update()
            bar.set_postfix(failed=sum(o["status"] == "failed" for o in outcome.values()))
            bar.write(f"{run}: {outcome[run]['status']}"
                      + (f" ({outcome[run]['error']})" if outcome[run]["status"] == "failed" else ""))
    except KeyboardInterrupt:
        for ref in waiting:
            ray.cancel(ref, force=True)
        bar.write(f"interrupted: {len(todo) - len(waiting)} runs kept, {len(waiting)} stopped; "
                  "run the same sweep again to run only what is missing")
        raise
    finally:
        bar.close()
        if ours:
            ray.shutdown()
    return outcome


def _collect(ray, ref, run: SweepRun, started: float) -> dict:
    """A finished task's outcome; its metrics written into this machine's ``data/`` (as the
    worker wrote them, when the worker is another machine)."""
    try:
        metrics, relative = ray.get(ref)
    except Exception as error:  # the run raised, or its worker died more often than retried
        cause = getattr(error, "cause", None) or error
        return {"status": "failed", "error": f"{type(cause).__name__}: {str(cause).strip().splitlines()[-1][:300]}"}
    path = data_dir() / (relative or Path("results", "sweep", run.experiment, f"{metrics['profile']}-seed{run.seed}",
                                          run.variant or "", "metrics.json"))
    text = json.dumps(metrics, indent=1)
    if not path.is_file() or json.loads(path.read_text()) != json.loads(text):
        with atomic_path(path) as tmp:
            tmp.write_text(text)
    return {"status": "done", "path": str(path), "wall_seconds": metrics.get("wall_seconds"),
            "since_start": round(time.time() - started, 1)}


__all__ = ["SweepRun", "variants_of", "parse_seeds", "parse_runs", "finished", "check_address", "check_joinable",
           "start_ray", "RayStartFailed", "sweep"]
