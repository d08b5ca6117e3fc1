"""One gradient-descent loop for every model: validation, early stopping, checkpoints, resume.

:func:`train` repeats ``loss_fn(sample("train"))`` steps, evaluates on ``sample("val")``
every ``eval_every`` steps, keeps the best weights, and writes a checkpoint (model,
optimiser, step, the sampling RNG states, history, config) atomically after every
evaluation. Calling it again with the same checkpoint path resumes where it stopped and
reaches the same weights as an uninterrupted run on a CPU. A changed config, or a
non-finite loss, stops with a clear message; the last good checkpoint is kept.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.runs import atomic_path


class ConfigMismatch(ValueError):
    """Resuming a run whose saved config differs from the one given."""


class NonFiniteLoss(FloatingPointError):
    """A loss term or the gradient norm became NaN or infinite; the message names the model,
    the update and the term, and where the last good checkpoint is."""


def gradient_step(name: str, update: int, terms: dict, optimiser: torch.optim.Optimizer, parameters, *,
                  clip_norm: float | None = None, kept: str = "no checkpoint is written by this loop") -> float:
    """The one guarded update of every gradient loop in the package (vision, memory, RSSM,
    AlphaZero heads, reward model, diagnosis probes).

    ``terms``: scalar loss tensors, ``terms["loss"]`` the one to minimise. Checks that every
    term is finite, backpropagates, takes the gradient norm of ``parameters`` (clipping it at
    ``clip_norm`` if given), checks that it is finite, then steps. A non-finite term or norm
    raises :class:`NonFiniteLoss` before any weight changes, naming ``name`` (the model),
    ``update`` (1-based) and the term, and saying ``kept`` (where the last good checkpoint
    is). Returns the gradient norm (before clipping).
    """
    bad = {k: float(v.detach()) for k, v in terms.items() if not torch.isfinite(v).all()}
    if bad:
        raise NonFiniteLoss(f"{name}: non-finite loss term {', '.join(f'{k} = {v}' for k, v in bad.items())} at "
                            f"update {update} (terms: { {k: round(float(v.detach()), 4) for k, v in terms.items()} }); "
                            f"stopped before that update; {kept}")
    optimiser.zero_grad(set_to_none=True)
    terms["loss"].backward()
    parameters = [p for p in parameters if p.grad is not None]
    if clip_norm is None:
        norm = torch.nn.utils.get_total_norm([p.grad for p in parameters])
    else:
        norm = torch.nn.utils.clip_grad_norm_(parameters, clip_norm)
    if not torch.isfinite(norm):
        optimiser.zero_grad(set_to_none=True)
        raise NonFiniteLoss(f"{name}: non-finite gradient norm ({float(norm)}) at update {update}; stopped "
                            f"before that update; {kept}")
    optimiser.step()
    return float(norm)


def config_dict(config) -> dict:
    return dataclasses.asdict(config) if dataclasses.is_dataclass(config) else dict(config)


def with_added_defaults(cls, saved: dict) -> dict:
    """A config dict saved by a run, with every field of dataclass ``cls`` that it lacks (added
    after the run was saved) set to what the run did: the field's default, or the value in
    ``cls.ADDED_AS`` where the default has changed since the field was added."""
    before = getattr(cls, "ADDED_AS", {})
    added = {f.name: before.get(f.name, f.default) for f in dataclasses.fields(cls) if f.name not in saved}
    return {**saved, **added}


def check_same_config(path: Path, saved: dict, wanted: dict) -> None:
    """Raise :class:`ConfigMismatch` naming the fields that differ between two configs."""
    if saved != wanted:
        keys = sorted(set(saved) | set(wanted))
        diff = {k: (saved.get(k), wanted.get(k)) for k in keys if saved.get(k) != wanted.get(k)}
        raise ConfigMismatch(f"{path} was written with another config: {diff} (saved, given); "
                             "use another run folder or delete the checkpoint to start over")


def check_resumable(path: Path, saved: tuple[dict, dict], wanted: tuple[dict, dict],
                    resumable: tuple[str, ...]) -> None:
    """Raise :class:`ConfigMismatch` unless a run saved with ``(config, task)`` = ``saved`` may
    resume as ``wanted``: only the config fields in ``resumable`` may differ (``task``: what the
    run was trained on, e.g. the game and a fingerprint of the models' weights)."""
    def comparable(config: dict, task: dict) -> dict:
        kept = {k: v for k, v in config.items() if k not in resumable}
        return {**kept, **{f"task.{k}": v for k, v in task.items()}}

    try:
        check_same_config(path, comparable(*saved), comparable(*wanted))
    except ConfigMismatch as error:
        raise ConfigMismatch(f"cannot resume: {error} (only {', '.join(resumable)} may change)") from None


def train(model: torch.nn.Module, optimiser: torch.optim.Optimizer, loss_fn: Callable[[dict], dict],
          sample: Callable[[str, np.random.Generator], dict], *, steps: int, checkpoint: str | Path,
          config, seed: int = 0, eval_every: int = 100, eval_batches: int = 4, patience: int | None = None,
          clip_norm: float | None = None, desc: str = "training", progress: bool = True) -> list[dict]:
    """Train ``model`` for up to ``steps`` updates; return the evaluation history.

    ``sample(split, rng)`` returns a batch for ``split`` in ``("train", "val")``;
    ``loss_fn(batch)`` returns a dict of scalar tensors with a ``"loss"`` entry.
    ``patience``: stop after this many evaluations without a better validation loss.
    The best weights (lowest validation loss) are saved beside ``checkpoint`` with the
    suffix ``.best.pt`` and loaded into ``model`` at the end. The checkpoint keeps the seconds
    spent training over every sitting (:func:`trained_seconds`).
    """
    checkpoint = Path(checkpoint)
    best_path = checkpoint.with_suffix(".best.pt")
    wanted = config_dict(config)
    state = {"step": 0, "best": math.inf, "bad_evals": 0, "history": [], "stopped": False,
             "rng": np.random.default_rng(seed).bit_generator.state, "torch_rng": _seeded_torch_state(seed)}
    if checkpoint.exists():
        state = _resume(checkpoint, model, optimiser, wanted)
    rng = np.random.default_rng()
    rng.bit_generator.state = state["rng"]
    torch.set_rng_state(state["torch_rng"])
    bar = tqdm(total=steps, initial=state["step"], desc=desc, disable=not progress)
    sitting, before = time.perf_counter(), state.get("seconds", 0.0)  # a checkpoint of an older file holds none
    while state["step"] < steps and not state["stopped"]:
        model.train()
        terms = loss_fn(sample("train", rng))
        kept = f"the last good checkpoint is kept at {checkpoint}" if checkpoint.exists() else "no checkpoint yet"
        gradient_step(desc, state["step"] + 1, terms, optimiser, model.parameters(), clip_norm=clip_norm, kept=kept)
        state["step"] += 1
        bar.update(1)
        if state["step"] % eval_every == 0 or state["step"] == steps:
            _evaluate(model, loss_fn, sample, rng, eval_batches, terms, state, patience, best_path)
            bar.set_postfix(train=f"{state['history'][-1]['train_loss']:.4g}", val=f"{state['history'][-1]['val_loss']:.4g}")
            state["rng"], state["torch_rng"] = rng.bit_generator.state, torch.get_rng_state()
            state["seconds"] = before + time.perf_counter() - sitting
            _save(checkpoint, model, optimiser, state, wanted)
    bar.close()
    if best_path.exists():
        model.load_state_dict(torch.load(best_path, weights_only=True))
    return state["history"]


def _seeded_torch_state(seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return generator.get_state()


@torch.no_grad()
def _evaluate(model, loss_fn, sample, rng, eval_batches, train_terms, state, patience, best_path) -> None:
    model.eval()
    val_terms = [loss_fn(sample("val", rng)) for _ in range(eval_batches)]
    record = {"step": state["step"], "train_loss": float(train_terms["loss"].detach())}
    for key in val_terms[0]:
        record[f"val_{key}"] = float(np.mean([float(t[key]) for t in val_terms]))
    state["history"].append(record)
    if record["val_loss"] < state["best"]:
        state["best"], state["bad_evals"] = record["val_loss"], 0
        with atomic_path(best_path) as tmp:
            torch.save(model.state_dict(), tmp)
    else:
        state["bad_evals"] += 1
        state["stopped"] = patience is not None and state["bad_evals"] >= patience


def _save(path: Path, model, optimiser, state: dict, config: dict) -> None:
    with atomic_path(path) as tmp:
        torch.save({"model": model.state_dict(), "optimiser": optimiser.state_dict(), "state": state,
                    "config": config}, tmp)


def _resume(path: Path, model, optimiser, wanted: dict) -> dict:
    try:
        saved = torch.load(path, weights_only=False)
    except Exception as error:  # a truncated or foreign file
        raise ValueError(f"cannot read checkpoint {path}: {error}; delete it to start over") from error
    check_same_config(path, saved["config"], wanted)
    model.load_state_dict(saved["model"])
    optimiser.load_state_dict(saved["optimiser"])
    return saved["state"]


def trained_seconds(checkpoint: str | Path) -> float:
    """The seconds a :func:`train` checkpoint spent training, summed over every sitting up to its
    last save (0 where there is no checkpoint, or it was written before it kept them)."""
    path = Path(checkpoint)
    if not path.is_file():
        return 0.0
    return float(torch.load(path, weights_only=False, map_location="cpu")["state"].get("seconds", 0.0))


def load_weights(path: str | Path, model: torch.nn.Module) -> torch.nn.Module:
    """Load the weights of a ``.best.pt`` file or a checkpoint into ``model``."""
    saved = torch.load(path, weights_only=False, map_location="cpu")
    model.load_state_dict(saved["model"] if "optimiser" in saved else saved)
    return model
