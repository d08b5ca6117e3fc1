"""Small helpers shared by every module: device choice, seeding, atomic file writes, timing,
weight fingerprints."""
from __future__ import annotations

import atexit
import concurrent.futures
import functools
import hashlib
import json
import multiprocessing
import os
import pickle
import random
import sys
import time
from contextlib import contextmanager, nullcontext
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm


def device() -> torch.device:
    """CUDA when present, the CPU otherwise."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def half_precision(dev: torch.device):
    """A context for fast computation on ``dev``: bfloat16 autocast where the hardware computes
    in bfloat16 natively (CUDA, or a CPU with AVX-512 BF16 or AMX), else nothing (float32), so a
    machine without it is not slowed by emulation. On this project's 2-core CPU it halves the
    Sokoban model's time per expansion (its predicted boards agreed with float32 on 8,191 of
    8,192 agent transitions) and makes its training 1.6x faster at the same exactness."""
    if dev.type == "cuda" and torch.cuda.is_bf16_supported():
        return torch.autocast("cuda", dtype=torch.bfloat16)
    native = (getattr(torch.cpu, name, lambda: False)() for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported"))
    if dev.type == "cpu" and any(native):
        return torch.autocast("cpu", dtype=torch.bfloat16)
    return nullcontext()


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


# Classes that checkpoints pickled under the package's earlier layout (one folder per kind:
# models/, agents/, planning/), and where they live now; read_pickle finds them there.
MOVED_CLASSES = {
    ("wmthesis.agents.alphazero", "Game"): "wmthesis.alphazero.replay",
    ("wmthesis.agents.controller_training", "SeededNormal"): "wmthesis.world_models.evolution",
}


class _Unpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        return super().find_class(MOVED_CLASSES.get((module, name), module), name)


def read_pickle(path: str | os.PathLike):
    """The object pickled at `path`; a truncated or corrupt file raises a ValueError that names
    it (files written through :func:`atomic_path` are whole unless copied or edited by hand).
    Classes pickled under the earlier layout are found where they live now (:data:`MOVED_CLASSES`)."""
    with open(path, "rb") as f:
        try:
            return _Unpickler(f).load()
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


@contextmanager
def timed(timings: dict | None, key: str):
    start = time.perf_counter()
    yield
    if timings is not None:
        timings[key] += time.perf_counter() - start


def fingerprint(model) -> str | None:
    """A hash of a module's weights (None for anything else, e.g. a plain function)."""
    if not isinstance(model, torch.nn.Module):
        return None
    digest = hashlib.sha1()
    for name, tensor in model.state_dict().items():
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


# ----------------------------------------------------------------------------- held folders
LOCK_NAME = ".wmthesis-lock"
_held: dict[Path, int] = {}  # folders this process holds -> how many holders inside it


class FolderHeld(RuntimeError):
    """Another live process holds a run's data folder."""


def hold(folder: str | os.PathLike) -> Path:
    """Hold ``folder`` for this process (until :func:`release` or exit): a lock file in it names
    the process id, the command line and the start time. A folder held by another live process
    raises :class:`FolderHeld` naming the holder; a lock left by a dead process is taken over,
    with a message. Holding again from the same process only counts. Returns the folder."""
    folder = Path(folder).resolve()
    if folder in _held:
        _held[folder] += 1
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / LOCK_NAME
    mine = {"pid": os.getpid(), "command": " ".join(sys.argv) or sys.executable,
            "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    while True:
        try:
            with open(lock, "x") as f:
                json.dump(mine, f)
            break
        except FileExistsError:
            holder = _read_lock(lock)
            if holder is not None and _alive(holder.get("pid")):
                raise FolderHeld(f"{folder} is held by another run: process {holder.get('pid')} "
                                 f"({holder.get('command')!r}, since {holder.get('started')}); wait for it to end, "
                                 f"or use another seed or data folder") from None
            print(f"{folder}: taking over the lock of a run that is gone ({holder}); its finished steps resume",
                  file=sys.stderr)
            lock.unlink(missing_ok=True)
    _held[folder] = 1
    return folder


def release(folder: str | os.PathLike) -> None:
    """Let go of one hold of ``folder``; the lock file goes with the last."""
    folder = Path(folder).resolve()
    if folder not in _held:
        return
    _held[folder] -= 1
    if _held[folder] == 0:
        del _held[folder]
        (folder / LOCK_NAME).unlink(missing_ok=True)


def releasing_holds(fn):
    """Decorator: folders :func:`hold` took during the call are let go when it returns or fails."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        before = dict(_held)
        try:
            return fn(*args, **kwargs)
        finally:
            for folder, count in list(_held.items()):
                for _ in range(count - before.get(folder, 0)):
                    release(folder)
    return wrapper


@atexit.register
def _release_all() -> None:
    for folder in list(_held):
        _held[folder] = 1
        release(folder)


def _read_lock(lock: Path) -> dict | None:
    try:
        return json.loads(lock.read_text())
    except (OSError, ValueError):
        return None


def _alive(pid) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    if pid == os.getpid():
        return False  # our own lock from before a fork/exec is stale for this holder count
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def process_pool(workers: int | None = None):
    """A pool of spawned processes (one torch thread each) that several :func:`parallel_calls`
    share, started once: ``workers`` (by default two on a machine with 2 cores or more), or a
    ``nullcontext`` of None where one process would do. Its processes start at the first call."""
    workers = min(os.cpu_count() or 1, 2) if workers is None else workers
    if workers <= 1:
        return nullcontext(None)
    return concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                  initializer=worker_init, initargs=(1,))


def parallel_calls(calls: list[tuple], progress: bool = True, on_done=None, executor=None) -> list:
    """``fn(*args)`` for each ``(fn, *args)`` in ``calls`` (module-level functions), two at a
    time in spawned processes with one torch thread each on a machine with 2 cores or more
    (small networks gain less from a second thread than from a second process), or in
    ``executor`` (:func:`process_pool`) where given; results in order. ``on_done(index, result)``
    is called as each finishes (to save it at once)."""
    on_done = on_done or (lambda index, result: None)
    if executor is not None:
        return _gathered(executor, calls, progress, on_done)
    workers = min(len(calls), os.cpu_count() or 1, 2)
    if workers <= 1:
        results = []
        for index, (fn, *args) in enumerate(calls):
            results.append(fn(*args))
            on_done(index, results[-1])
        return results
    with process_pool(workers) as executor:
        return _gathered(executor, calls, progress, on_done)


def _gathered(executor, calls: list[tuple], progress: bool, on_done) -> list:
    """``calls`` submitted to ``executor``; ``on_done`` as each finishes; results in order."""
    futures = {executor.submit(fn, *args): index for index, (fn, *args) in enumerate(calls)}
    for future in tqdm(concurrent.futures.as_completed(futures), total=len(futures), desc="runs",
                       disable=not progress):
        on_done(futures[future], future.result())
    return [future.result() for future in futures]


def set_threads(threads: int) -> None:
    """torch's intra-op threads in this process."""
    torch.set_num_threads(threads)


def worker_init(threads: int) -> None:
    """A pool worker's initializer: ``threads`` torch threads, and (on Linux) an end with its
    parent: a driver killed by a signal leaves no orphan workers computing on."""
    set_threads(threads)
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1: PR_SET_PDEATHSIG
        if os.getppid() == 1:  # the parent died before the call above
            os._exit(1)
