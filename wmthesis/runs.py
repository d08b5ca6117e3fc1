"""The run store: where a run's files live, the lock on its folder, files written whole, keyed
caches of played bouts and levels, resumable jobs, and the header of every ``metrics.json``.

A run of experiment ``E`` (variant ``V``, seed ``S``, profile ``P``) keeps its artifacts (stores,
checkpoints, caches) in :func:`work_folder` ``data/P/E/[V-]seedS`` and its results (figures,
``metrics.json``, recordings) in :func:`results_folder` ``data/results/E/P-seedS[/V]``. Every
step that writes goes through :func:`atomic_path` (a crash leaves the previous file), and every
long step saves what it has done as it goes (:func:`played_groups`, :func:`run_jobs`), so a run
cut off resumes where it stopped.
"""
from __future__ import annotations

import atexit
import errno
import functools
import json
import os
import platform
import shutil
import sys
import tempfile
from collections.abc import Callable
from contextlib import contextmanager
from datetime import date, datetime, timezone
from pathlib import Path

import numpy as np

from wmthesis.utils import data_dir, parallel_calls, process_alive


# ----------------------------------------------------------------------------- folders
def work_folder(profile: str, experiment: str, seed: int, variant: str | None = None) -> Path:
    """A run's artifacts: ``data/<profile>/<experiment>/[<variant>-]seed<seed>`` (created)."""
    return data_dir(profile, experiment, f"seed{seed}" if variant is None else f"{variant}-seed{seed}")


def results_folder(experiment: str, profile: str, seed: int, variant: str | None = None) -> Path:
    """A run's results: ``data/results/<experiment>/<profile>-seed<seed>[/<variant>]`` (created)."""
    return data_dir("results", experiment, f"{profile}-seed{seed}", *(() if variant is None else (variant,)))


_RUNNER: list = []  # the package's ``reproduce``, registered by :mod:`wmthesis.experiments`


def register_runner(runner: Callable) -> None:
    """The function that runs an experiment, ``runner(name, profile, seed, variant, progress)``
    (:func:`wmthesis.experiments.reproduce`): how one recipe has another's run made, without
    importing it (:func:`built_on`)."""
    _RUNNER[:] = [runner]


def built_on(experiment: str, profile: str, seed: int, variant: str | None = None, progress: bool = True) -> dict:
    """The metrics of the run of ``experiment`` that a recipe builds on (same profile and seed):
    made first, resumed, or returned as it is by the registered runner (:func:`register_runner`)."""
    if not _RUNNER:
        raise RuntimeError("no experiment runner registered: import wmthesis.experiments first")
    return _RUNNER[0](experiment, profile, seed, variant, progress)


# ----------------------------------------------------------------------------- files written whole
class DiskFull(OSError):
    """No space left on the folder a file was being written to (errno ENOSPC): the file was not
    written, and every earlier file is intact."""

    def __init__(self, folder: str | os.PathLike, what: str):
        super().__init__(errno.ENOSPC, f"no space left on {folder}: {what}; free some space and run it again")


MIN_FREE_BYTES = 1 << 20  # below this a failed write is read as a full disk (torch and HDF5 hide ENOSPC)


def is_disk_full(error: BaseException, folder: str | os.PathLike) -> bool:
    """Whether ``error``, raised while writing into ``folder``, is a full disk: ENOSPC, a message
    that says so, or any failed write on a folder with less than :data:`MIN_FREE_BYTES` free."""
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    if "no space left" in str(error).lower():
        return True
    try:
        return shutil.disk_usage(folder).free < MIN_FREE_BYTES
    except OSError:
        return False


def check_space(folder: str | os.PathLike, need: int, what: str) -> None:
    """:class:`DiskFull` naming ``folder`` where it has fewer than ``need`` bytes free (plus
    :data:`MIN_FREE_BYTES`): checked before a write that cannot be undone cleanly (an HDF5 append)."""
    free = shutil.disk_usage(folder).free
    if free < need + MIN_FREE_BYTES:
        raise DiskFull(folder, f"{what} needs about {need / 2**20:.1f} MiB, {free / 2**20:.1f} MiB are free")


def check_writable(path: str | os.PathLike, suffix: str | None = None, make_folder: bool = False) -> Path:
    """``path`` if a file can be written there: it ends in ``suffix`` (where given), is not a
    folder, and its folder exists (``make_folder``: is made) and takes a new file (tried: a
    read-only mount or ``/proc`` passes ``os.access`` as root). ValueError naming the user's path
    otherwise, before any work."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder: name a file in it")
    if suffix is not None and path.suffix != suffix:
        raise ValueError(f"{path}: name a {suffix} file")
    if make_folder:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise ValueError(f"{path}: cannot create its folder ({error.strerror}); choose a folder you can write") from None
    if not path.parent.is_dir():
        raise ValueError(f"{path} cannot be written: its folder {path.parent} does not exist")
    try:
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.probe"):
            pass
    except OSError as error:
        raise ValueError(f"{path} cannot be written: its folder {path.parent} takes no new file "
                         f"({error.strerror or error})") from None
    return path


@contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to ``path``; move it into place only if the block succeeds.

    A crash mid-write leaves the previous file (if any) untouched, and no partial file behind;
    a write that fails on a full disk raises :class:`DiskFull` naming the folder.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    except Exception as error:
        if not isinstance(error, DiskFull) and is_disk_full(error, path.parent):
            raise DiskFull(path.parent, f"{path.name} was not written") from error
        if isinstance(error, OSError) and str(getattr(error, "filename", "")) == str(tmp):  # name the user's file
            raise type(error)(error.errno, error.strerror, str(path)) from None
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path: str | os.PathLike, value, indent: int | None = 1, default=None) -> Path:
    """``value`` as JSON at ``path``, written whole (:func:`atomic_path`); returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(value, indent=indent, default=default))
    return path


def read_json(path: str | os.PathLike) -> dict | None:
    """A cached JSON file, or None when it is missing or corrupt (the step runs again)."""
    path = Path(path)
    try:
        return json.loads(path.read_text()) if path.is_file() else None
    except ValueError:
        return None


def jsonable(value):
    """``value`` with numpy arrays and scalars as lists and numbers, NaN as None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (float, np.floating)):
        return None if not np.isfinite(value) else float(value)
    return value


def cached(path: Path, fn: Callable, *args):
    """``fn(*args)``, kept in ``path`` as JSON: a re-run reads it (delete it to compute again)."""
    value = read_json(path)
    if value is None:
        value = fn(*args)
        write_json(path, value, indent=None)
    return value


# ----------------------------------------------------------------------------- the header of a metrics.json
def machine_name() -> str:
    """This machine as the results name it: ``host (arch, N cores)``."""
    return f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)"


def run_header(experiment: str, profile: str, seed: int, seconds: float, **run) -> dict:
    """The first entries of a ``metrics.json``: the experiment, ``run``'s own (its variant, ...),
    profile and seed, today's date, this machine, its torch threads (a seed repeats its curve on
    a CPU only with the same number: reductions split differently) and the wall time of ``seconds``."""
    import torch  # heavy: loaded when a run writes its metrics, not when the command line starts

    from wmthesis.schemas import METRICS_VERSION

    return {"schema_version": METRICS_VERSION, "experiment": experiment, **run, "profile": profile, "seed": seed,
            "date": date.today().isoformat(),
            "machine": machine_name(),
            "threads": torch.get_num_threads(), "wall_seconds": round(seconds, 1)}


RUN_CIRCUMSTANCES = ("date", "machine", "threads", "wall_seconds", "files", "schema_version")  # when, where, how long, how written; not what


def unchanged_run(path: str | os.PathLike, metrics: dict) -> dict | None:
    """The metrics already at ``path`` where they hold what ``metrics`` holds, but for when, where and
    how long the run took (:data:`RUN_CIRCUMSTANCES`): a finished run asked again, with nothing to
    write; else None."""
    earlier = read_json(path)
    what = lambda m: {k: v for k, v in json.loads(json.dumps(m)).items() if k not in RUN_CIRCUMSTANCES}  # noqa: E731
    return earlier if earlier is not None and what(earlier) == what(metrics) else None


def first_run_seconds(path: Path, seconds: float, same: Callable[[dict], bool] | None = None) -> float:
    """The wall time of the run that computed everything: kept from an earlier metrics file at
    ``path`` (its ``first_run_wall_seconds``, or the ``wall_seconds`` of a file written before
    that field; a resumed or cached run is faster) where ``same(earlier)`` says it measured the
    same training (None: any earlier file), else this run's ``seconds``."""
    try:
        earlier = json.loads(Path(path).read_text())
        if same is not None and not same(earlier):
            return seconds
        return float(earlier.get("first_run_wall_seconds", earlier["wall_seconds"]))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return seconds


def over_sittings(seconds: float, *stages: tuple[float | None, float]) -> float:
    """A run's wall time over every sitting: this call's ``seconds`` plus, for each resumable stage
    ``(recorded, here)``, the time its checkpoints record (training, evolution or rounds, summed over
    every sitting; None: none recorded) beyond this call's own share of it (``here``, the seconds
    this call spent in that stage)."""
    return seconds + sum(max(0.0, (recorded or 0.0) - here) for recorded, here in stages)


# ----------------------------------------------------------------------------- agent files
def save_agent_file(path: str | os.PathLike, form: str, version: int, **fields) -> Path:
    """A trained agent in one torch file at ``path``, written whole: its ``form`` and ``version``
    and ``fields`` (what the agent plays with); returns the path (:func:`read_agent_file` reads it)."""
    import torch  # heavy: loaded when an agent is written

    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"format": form, "version": version, **fields}, tmp)
    return path


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of the file at ``path``, in hex."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_agent_file(path: str | os.PathLike, kind: str, form: str, version: int) -> dict:
    """The dict an agent file at ``path`` holds; a missing file, a corrupt one or one of another
    ``form`` or version raises an error naming it (``kind``: what it should hold, for the message)."""
    import torch  # heavy: loaded when an agent is read

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {kind} agent at {path}")
    try:
        saved = torch.load(path, weights_only=False, map_location="cpu")
        stamp = (saved.get("format"), saved.get("version"))
    except Exception as error:  # truncated, or not a torch file
        raise ValueError(f"cannot read {path}: {error}") from error
    if stamp != (form, version):
        raise ValueError(f"{path} is not a {form} file of version {version} (it says {stamp})")
    return saved


# ----------------------------------------------------------------------------- keyed caches of played bouts
def cached_for(path: Path, key: dict, read_key: Callable[[dict], dict] | None = None) -> dict | None:
    """The JSON cache at ``path`` if it was written for ``key``, else None. ``read_key`` brings a
    saved key up to date first (a config saved before a field was added reads as what it did)."""
    saved = read_json(path)
    if saved is None or not isinstance(saved.get("key"), dict):
        return None
    found = dict(saved["key"]) if read_key is None else read_key(dict(saved["key"]))
    return saved if found == key else None


def played_bouts(path: Path, key: dict, progress: bool, calls: list[tuple],
                 read_key: Callable[[dict], dict] | None = None) -> list[dict]:
    """``calls`` (one bout each), each bout saved in ``path`` as it ends: a run cut off plays
    only the bouts it had not finished (those saved for the same ``key``, :func:`cached_for`)."""
    return played_groups([(path, key, calls, read_key)], progress)[0]


def played_groups(groups: list[tuple], progress: bool, executor=None) -> list[list[dict]]:
    """:func:`played_bouts` for each ``(path, key, calls, read_key)`` of ``groups``, all in one
    pool (``executor``, a :func:`~wmthesis.utils.process_pool`; two at a time by default),
    submitted group by group: the first groups end first. Returns each group's plays."""
    done, todo = [], []
    for g, (path, key, calls, read_key) in enumerate(groups):
        saved = cached_for(path, key, read_key)
        done.append({int(i): play for i, play in (saved or {}).get("plays", {}).items()})
        todo += [(g, i) for i in range(len(calls)) if i not in done[g]]

    def save(index: int, play: dict) -> None:
        g, i = todo[index]
        done[g][i] = play
        write_json(groups[g][0], {"key": groups[g][1], "plays": done[g]})

    parallel_calls([groups[g][2][i] for g, i in todo], progress, on_done=save, executor=executor)
    return [[done[g][i] for i in range(len(calls))] for g, (_, _, calls, _) in enumerate(groups)]


# ----------------------------------------------------------------------------- resumable jobs
def partial_path(path: Path) -> Path:
    """Where a job saving to ``path`` keeps what it has done so far (a job cut off resumes there)."""
    return path.with_name(path.stem + ".partial.json")


def run_jobs(jobs: dict, progress: bool) -> None:
    """Run each job ``key: (path, (fn, *args), record)`` whose JSON at ``path`` is missing, or was
    saved with another ``record`` (its ``"search"`` entry; None: any), two at a time, each saved
    as it finishes and its :func:`partial_path` then removed (a re-run computes only what is missing)."""
    def saved(path: Path, record: dict | None) -> bool:
        result = read_json(path)
        return result is not None and (record is None or result.get("search") == record)

    missing = [key for key, (path, _, record) in jobs.items() if not saved(path, record)]

    def keep(index: int, result: dict) -> None:
        path = jobs[missing[index]][0]
        write_json(path, result, indent=None)
        partial_path(path).unlink(missing_ok=True)

    parallel_calls([jobs[key][1] for key in missing], progress, keep)


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
    return process_alive(pid)


__all__ = ["work_folder", "results_folder", "register_runner", "built_on", "DiskFull", "MIN_FREE_BYTES", "is_disk_full",
           "check_space", "check_writable", "atomic_path", "write_json", "read_json", "jsonable", "cached",
           "run_header", "first_run_seconds", "over_sittings", "cached_for", "played_bouts", "played_groups", "partial_path",
           "run_jobs", "LOCK_NAME", "FolderHeld", "hold", "release", "releasing_holds", "save_agent_file",
           "read_agent_file"]
