"""Small helpers shared by every module: device choice, seeding, choices checked, the data folder,
timing, weight fingerprints, pickles read back, pools of processes (files and run folders:
:mod:`wmthesis.runs`)."""
from __future__ import annotations

import concurrent.futures
import hashlib
import multiprocessing
import os
import pickle
import random
import re
import sys
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

if TYPE_CHECKING:
    import torch


def device() -> torch.device:
    """CUDA when present, the CPU otherwise."""
    import torch  # heavy: loaded when first needed (the command line starts without it)

    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def half_precision(dev: torch.device):
    """A context for fast computation on ``dev``: bfloat16 autocast where the hardware computes
    in bfloat16 natively (CUDA, or a CPU with AVX-512 BF16 or AMX), else nothing (float32), so a
    machine without it is not slowed by emulation. On this project's 2-core CPU it halves the
    Sokoban model's time per expansion (its predicted boards agreed with float32 on 8,191 of
    8,192 agent transitions) and makes its training 1.6x faster at the same exactness."""
    import torch  # heavy: loaded when first needed (the command line starts without it)

    if dev.type == "cuda" and torch.cuda.is_bf16_supported():
        return torch.autocast("cuda", dtype=torch.bfloat16)
    native = (getattr(torch.cpu, name, lambda: False)() for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported"))
    if dev.type == "cpu" and any(native):
        return torch.autocast("cpu", dtype=torch.bfloat16)
    return nullcontext()


def seed_everything(seed: int) -> np.random.Generator:
    """Seed Python, NumPy and torch; return a fresh NumPy generator for explicit use."""
    import torch  # heavy: loaded when first needed (the command line starts without it)

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return np.random.default_rng(seed)


# Classes that checkpoints pickled under the package's earlier layouts (one folder per kind:
# models/, agents/, planning/; configs in one module; the learned value inside planet/), and
# where they live now; read_pickle finds them there.
MOVED_CLASSES = {
    ("wmthesis.agents.alphazero", "Game"): "wmthesis.alphazero.replay",
    ("wmthesis.agents.controller_training", "SeededNormal"): "wmthesis.world_models.evolution",
    ("wmthesis.config", "VisionConfig"): "wmthesis.world_models.config",
    ("wmthesis.config", "MemoryConfig"): "wmthesis.world_models.config",
    ("wmthesis.config", "ControllerConfig"): "wmthesis.world_models.config",
    ("wmthesis.config", "PlaNetConfig"): "wmthesis.planet.config",
    ("wmthesis.config", "LatentValueConfig"): "wmthesis.value.config",
    ("wmthesis.config", "ValuePlannerConfig"): "wmthesis.value.config",
    ("wmthesis.planet.config", "LatentValueConfig"): "wmthesis.value.config",
    ("wmthesis.planet.config", "ValuePlannerConfig"): "wmthesis.value.config",
    ("wmthesis.config", "SearchConfig"): "wmthesis.planet.config",
    ("wmthesis.config", "AlphaZeroConfig"): "wmthesis.alphazero.config",
    ("wmthesis.config", "SokobanSearchConfig"): "wmthesis.sokoban_search.config",
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


def check_finite(name: str, values) -> None:
    """ValueError naming ``name`` where ``values`` (a numpy array or torch tensor) hold NaN or
    infinity: a model refuses them at its door rather than answering with NaN or action 0."""
    array = values.detach().cpu().numpy() if hasattr(values, "detach") else np.asarray(values)
    if array.dtype.kind in "fc" and not np.isfinite(array).all():
        raise ValueError(f"{name} hold NaN or infinity ({int((~np.isfinite(array)).sum())} of {array.size} values)")


MAX_SEED = 2**31 - 1  # seeds are 31-bit: every generator and store of the package takes them
MAX_SEEDS = 100  # seeds one command takes: a longer range is almost surely a typo


def check_seed(seed) -> int:
    """``seed`` as an int if it is an integer in 0..:data:`MAX_SEED`, else ValueError in one line
    (before any folder is made for it)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"a seed is an integer from 0 to {MAX_SEED:,}, got {seed!r}")
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"seeds are from 0 to {MAX_SEED:,} (31 bits), got {int(seed):,}")
    return int(seed)


def parse_seeds(text: str, most: int = MAX_SEEDS) -> list[int]:
    """``"0-4"`` -> [0, 1, 2, 3, 4]; ``"0,2,7"`` and ``"3"`` as written; a bad range, a seed above
    :data:`MAX_SEED` or more than ``most`` seeds raises ValueError (before anything is counted out)."""
    seeds: set[int] = set()
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if match is None:
            raise ValueError(f"--seeds {text!r}: {part!r} is not a seed or a range (e.g. 0-4 or 0,2,7)")
        low, high = int(match[1]), int(match[2] if match[2] is not None else match[1])
        if high < low:
            raise ValueError(f"--seeds {text!r}: the range {low}-{high} is empty (write it low-high)")
        if high > MAX_SEED:
            raise ValueError(f"--seeds {text!r}: seeds are at most {MAX_SEED:,} (31 bits), got {high:,}")
        if len(seeds) + high - low + 1 > most:
            raise ValueError(f"--seeds {text!r}: more than {most} seeds; name at most {most} in one command")
        seeds.update(range(low, high + 1))
    return sorted(seeds)


def data_dir(*parts: str) -> Path:
    """Where run-time artifacts go: ``$WMTHESIS_DATA`` if set, else the checkout's ``data/``.

    Extra ``parts`` are joined on and the folder is created.
    """
    root = os.environ.get("WMTHESIS_DATA")
    if root is not None and not root.strip():
        raise ValueError("WMTHESIS_DATA is set but empty: unset it (the checkout's data/) or name a folder")
    if root is None:
        checkout = Path(__file__).resolve().parents[1]
        root = checkout / "data" if (checkout / "pyproject.toml").exists() else Path.cwd() / "data"
    path = Path(root, *parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def shipped_dir() -> Path | None:
    """The checkout's ``data/``, where what the repository ships lies whatever ``$WMTHESIS_DATA``
    says (None outside a checkout)."""
    checkout = Path(__file__).resolve().parents[1]
    return checkout / "data" if (checkout / "pyproject.toml").exists() else None


def shown_path(path: str | os.PathLike) -> str:
    """``path`` as a reader should see it: under the data folder as ``data/...``, else as given
    (no machine's own folders in a notebook's outputs)."""
    path = Path(path)
    try:
        return str(Path("data") / path.resolve().relative_to(data_dir().resolve()))
    except ValueError:
        return str(path)


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


MAX_BOUTS = 1000  # the most bouts (or levels) one call plays: a bout is ~1,800 steps, so 1,000 is half an hour


def check_count(count, name: str, most: int) -> int:
    """``count``, a whole number from 1 to ``most``; ValueError naming ``name`` and the range otherwise."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 1 <= count <= most:
        raise ValueError(f"{name} must be a whole number from 1 to {most:,}, got {count!r}")
    return int(count)


def check_bouts(bouts, name: str = "bouts") -> int:
    """``bouts``, a whole number from 1 to :data:`MAX_BOUTS`; ValueError naming the range otherwise."""
    return check_count(bouts, name, MAX_BOUTS)


def masked(url: str) -> str:
    """``url`` with the password of its user part replaced by ``***`` (any scheme:
    ``postgresql://me:secret@host/db`` -> ``postgresql://me:***@host/db``); other text as is."""
    from urllib.parse import urlsplit, urlunsplit

    try:
        parts = urlsplit(url)
        if parts.password is None:
            return url
    except ValueError:
        return url
    user, host = parts.netloc.rsplit("@", 1)
    return urlunsplit(parts._replace(netloc=f"{user.split(':', 1)[0]}:***@{host}"))


def secret_free(text: str, url: str) -> str:
    """``text`` with ``url`` masked (:func:`masked`) and any other copy of its password too (an
    error a driver wrote with it)."""
    from urllib.parse import urlsplit

    try:
        password = urlsplit(url).password
    except ValueError:
        password = None
    text = text.replace(url, masked(url))
    return text.replace(password, "***") if password else text


def fingerprint(model) -> str | None:
    """A hash of a module's weights (None for anything else, e.g. a plain function)."""
    import torch  # heavy: loaded when first needed (the command line starts without it)

    if not isinstance(model, torch.nn.Module):
        return None
    digest = hashlib.sha1()
    for name, tensor in model.state_dict().items():
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` of this machine runs (another user's counts; a zombie, ended but not
    reaped by its parent, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:  # no /proc (not Linux): kill's answer stands
        return True


def default_processes() -> int:
    """The processes the package's pools use unless told: ``$WMTHESIS_PROCESSES`` where set (1:
    every call in the calling process, as on a 1-core machine), else two on a machine with 2 cores
    or more."""
    text = os.environ.get("WMTHESIS_PROCESSES")
    if text is None:
        return 2 if (os.cpu_count() or 1) >= 2 else 1
    if not text.strip().isdigit() or int(text) < 1:
        raise ValueError(f"WMTHESIS_PROCESSES must be a positive integer, got {text!r}")
    return int(text)


def process_pool(workers: int | None = None):
    """A pool of spawned processes (one torch thread each) that several :func:`parallel_calls`
    share, started once: ``workers`` (by default :func:`default_processes`), or a ``nullcontext``
    of None where one process would do by default. ``workers`` given: that many processes, one
    included. Its processes start at the first call."""
    if workers is None and default_processes() < 2:
        return nullcontext(None)
    workers = default_processes() if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                  initializer=worker_init, initargs=(1,))


def over_seeds(call, seeds, workers: int | None = None) -> dict:
    """``{seed: call(seed, executor)}`` for each of ``seeds``, seed after seed in threads that
    share one :func:`process_pool` of ``workers`` processes."""
    with process_pool(workers) as pool, concurrent.futures.ThreadPoolExecutor(max(1, len(seeds))) as threads:
        futures = {seed: threads.submit(call, seed, pool) for seed in seeds}
        return {seed: future.result() for seed, future in futures.items()}


def parallel_calls(calls: list[tuple], progress: bool = True, on_done=None, executor=None) -> list:
    """``fn(*args)`` for each ``(fn, *args)`` in ``calls`` (module-level functions), two at a
    time (:func:`default_processes`) in spawned processes with one torch thread each on a machine
    with 2 cores or more (small networks gain less from a second thread than from a second process), or in
    ``executor`` (:func:`process_pool`) where given; results in order. ``on_done(index, result)``
    is called as each finishes (to save it at once)."""
    on_done = on_done or (lambda index, result: None)
    if executor is not None:
        return _gathered(executor, calls, progress, on_done)
    workers = min(len(calls), default_processes())
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
    import torch  # heavy: loaded when first needed (the command line starts without it)

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
