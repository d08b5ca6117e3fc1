"""World Models on Sokoban, measured (thesis 5.3.1-5.3.3): the memory variants, their open-loop
rollouts and heads on validation episodes against baselines, and levels solved.

The thesis judged these models "with the eye of the researcher"; here every judgement is a
number: cells of the right type, one player, boxes kept (:func:`read_grid` of the predicted
frames), the heads' skill over a constant."""
from __future__ import annotations

import numpy as np
import torch

from wmthesis.data import EpisodeStore
from wmthesis.envs.sokoban import read_grid
from wmthesis.metrics import error_at, horizon_errors
from wmthesis.world_models.grid import grid_accuracy
from wmthesis.world_models.prediction import head_predictions, open_loop, open_loop_grid
from wmthesis.world_models.train import LatentStore, reconstruct, split_episodes


# Memory variants, all trained on the same random rollouts: name -> (input, memory kind,
# auxiliary value head). "rgb": the VAE's latents (16) of 64x64 frames; "grid": the 64 block
# types of the inner 8x8 cells, bypassing vision (5.3.2, see encode_grid_store).
VARIANTS = {
    "mdn": ("rgb", "mdn", False),                      # 5.3.1: the stochastic MDN-RNN
    "deterministic": ("rgb", "deterministic", False),  # 5.3.1: linear next-latent head (4.3.1)
    "auxiliary": ("rgb", "mdn", True),                 # 5.3.3: + value head (Monte-Carlo return)
    "grid": ("grid", "mdn", False),                    # 5.3.2: grid states, latent 64
    "grid-auxiliary": ("grid", "mdn", True),           # 5.3.3 on grid states
}


# Controllers evolved with CMA-ES in the real game, named by the memory variant whose [z h] they
# read: 5.3.1's (VAE + MDN-RNN), 5.3.2's (grid states) and 5.3.3's (grid states + auxiliary heads).
CONTROLLERS = ("mdn", "grid", "grid-auxiliary")


def check_same_episodes(latents: dict) -> None:
    """The frame and grid stores must hold the same episodes (same seeds: same levels, actions)."""
    rgb, grid = LatentStore(latents["rgb"]), LatentStore(latents["grid"])
    if not (np.array_equal(rgb.ends, grid.ends) and all(torch.equal(rgb.data[k], grid.data[k])
                                                        for k in ("actions", "rewards", "terminals"))):
        raise ValueError(f"{latents['rgb']} and {latents['grid']} hold different episodes; delete the "
                         "stores and latents under that folder to collect them again")


def levels_solved(returns, steps) -> int:
    """Levels solved. Each step costs 0.1 and boxes net at most +4 (10x10: 4 boxes), so an
    unsolved episode has ``return + 0.1 * steps <= 4``, a solved one (the +10) at least 11."""
    return int(np.sum(np.asarray(returns, float) + 0.1 * np.asarray(steps, float) > 5))


def evaluate_memories(vae, memories: dict, stores: dict, latents: dict, memory_cfg, evaluation: dict) -> dict:
    """Open-loop rollouts of every memory variant, and its heads' predictions, on validation
    episodes; with two baselines, "nothing moves" (the last real frame repeated) and the VAE's
    reconstructions of the true frames (the best a VAE-decoded prediction can look). Returns
    ``episodes``, ``vision``, ``memory`` and ``baselines`` (numbers and curves) and ``examples``
    (arrays for the figures)."""
    context, horizon, cutoff = evaluation["context"], evaluation["horizon"], evaluation["cutoff"]
    latent_stores = {source: LatentStore(path) for source, path in latents.items()}
    grid_latents = latent_stores["grid"]
    train_episodes, val_episodes = split_episodes(len(grid_latents), memory_cfg.val_fraction)
    lengths = grid_latents.ends - grid_latents.starts
    chosen = [int(i) for i in val_episodes if lengths[i] >= context + horizon][:evaluation["episodes"]]
    if not chosen:
        raise ValueError(f"no validation episode has the {context + horizon} steps of an open-loop rollout")
    names = [*VARIANTS, "nothing moves", "vae reconstruction"]
    curves = {name: {"pixel": [], "latent": [], "codes": []} for name in names}
    shown = min(3, len(chosen))
    examples = {"start": [], "truth": [], "prediction": {name: [] for name in names}}
    truth_codes, last_seen = [], []
    with EpisodeStore(stores["rgb"]) as rgb, EpisodeStore(stores["grid"]) as grid:
        for k, index in enumerate(chosen):
            episode = rgb.episode(index)
            frames, actions = episode["observations"], episode["actions"]
            grids = grid.episode(index)["observations"]
            truth = frames[context:context + horizon]
            truth_codes.append(grids[context:context + horizon])
            last_seen.append(grids[context - 1])
            results = {}
            for variant, (source, _, _) in VARIANTS.items():
                if source == "rgb":
                    result = open_loop(vae, memories[variant], frames, actions, context=context, horizon=horizon)
                    results[variant] = (result["prediction"], result["latent_error"], read_grid(result["prediction"]))
                else:
                    result = open_loop_grid(memories[variant], grids, actions, context=context, horizon=horizon)
                    results[variant] = (result["prediction"], result["latent_error"], result["prediction_grid"])
            still = np.repeat(frames[context - 1][None], horizon, axis=0)
            results["nothing moves"] = (still, None, np.repeat(grids[context - 1][None], horizon, axis=0))
            reconstruction = reconstruct(vae, truth)
            results["vae reconstruction"] = (reconstruction, None, read_grid(reconstruction))
            for name, (prediction, latent_error, codes) in results.items():
                curves[name]["pixel"].append(horizon_errors(truth, prediction))
                curves[name]["codes"].append(codes)
                if latent_error is not None:
                    curves[name]["latent"].append(latent_error)
                if k < shown:
                    examples["prediction"][name].append(prediction)
            if k < shown:
                examples["start"].append(frames[context - 1])
                examples["truth"].append(truth)
            if k == 0:
                examples["grid_state"] = (frames[context - 1], grids[context - 1])
        picks = chosen[:8]
        fig54 = np.stack([rgb.episode(i)["observations"][(37 * n) % lengths[i]] for n, i in enumerate(picks)])
    examples["fig54"] = (fig54, reconstruct(vae, fig54))

    truth_codes, last_seen = np.stack(truth_codes), np.stack(last_seen)
    summary = {}
    for name, curve in curves.items():
        entry = {"pixel_error": np.mean(curve["pixel"], axis=0),
                 **grid_accuracy(np.stack(curve["codes"]), truth_codes, last_seen)}
        if curve["latent"]:
            entry["latent_error"] = np.mean(curve["latent"], axis=0)
        entry["at_cutoff"] = {key: error_at(values, cutoff) for key, values in entry.items()}
        summary[name] = entry
    heads, examples["heads"] = evaluate_heads(memories, latent_stores, memory_cfg.discount, train_episodes,
                                              val_episodes[:evaluation["episodes"]])
    reconstruction = summary["vae reconstruction"]
    return {"episodes": len(chosen),
            "vision": {"reconstruction_pixel_error": float(np.mean(reconstruction["pixel_error"])),
                       "reconstruction_cell_accuracy": float(np.mean(reconstruction["cell_accuracy"]))},
            "memory": {variant: {"open_loop": summary[variant], **heads[variant]} for variant in VARIANTS},
            "baselines": {name: summary[name] for name in ("nothing moves", "vae reconstruction")},
            "examples": examples}


def evaluate_heads(memories: dict, latent_stores: dict, discount: float, train_episodes,
                   val_episodes) -> tuple[dict, dict]:
    """The reward head of every memory and the value head of the auxiliary ones on validation
    episodes (teacher forcing), against the truth and naive predictors: the training mean, and
    for the value the return of a level where nothing but the step cost ever happens (known
    from the time left alone). Returns the numbers by variant and the series for the figure."""
    numbers, series = {}, {}
    returns = {source: store.returns(discount).numpy() for source, store in latent_stores.items()}
    for variant, (source, _, auxiliary) in VARIANTS.items():
        store = latent_stores[source]
        rows = np.concatenate([np.arange(store.starts[i], store.ends[i]) for i in train_episodes])
        rewards = store.data["rewards"].numpy()
        collected = {key: [] for key in ("reward", "true_reward", "value", "true_value", "time_only")}
        for index in val_episodes:
            episode = store.episode(int(index))
            predicted = head_predictions(memories[variant], episode["mu"], episode["actions"])
            steps_left = np.arange(len(episode["actions"]), 0, -1)
            collected["reward"].append(predicted["reward"])
            collected["true_reward"].append(episode["rewards"].numpy())
            collected["true_value"].append(returns[source][store.starts[index]:store.ends[index]])
            collected["time_only"].append(-0.1 * (1 - discount ** steps_left) / (1 - discount))
            if auxiliary:
                collected["value"].append(predicted["value"])
        data = {key: np.concatenate(values) for key, values in collected.items() if values}
        numbers[variant] = {"reward_head": head_numbers(data["reward"], data["true_reward"], rewards[rows].mean(),
                                                         events=np.abs(data["true_reward"] + 0.1) > 1e-3)}
        if auxiliary:
            numbers[variant]["value_head"] = head_numbers(data["value"], data["true_value"],
                                                           returns[source][rows].mean(), time_only=data["time_only"])
        series[variant] = {"reward": data["reward"], "true_reward": data["true_reward"],
                           "episode": {key: values[0] for key, values in collected.items() if values}}
    return numbers, series


def head_numbers(predicted, true, constant: float, events=None, time_only=None) -> dict:
    """How well a head predicts ``true`` (N,): its MSE; a constant's (the training mean); the
    skill ``1 - mse / constant_mse`` (> 0: better than the constant); the correlation; on
    ``events`` (the rare steps where a box moved on or off a target) the same MSEs; the MSE of a
    predictor that knows only the time left (``time_only``)."""
    predicted, true = np.asarray(predicted, np.float64), np.asarray(true, np.float64)
    mse, constant_mse = float(np.mean((predicted - true) ** 2)), float(np.mean((constant - true) ** 2))
    correlation = (float(np.corrcoef(predicted, true)[0, 1])
                   if predicted.std() > 0 and true.std() > 0 else float("nan"))
    skill = 1 - mse / constant_mse if constant_mse > 0 else float("nan")
    out = {"mse": mse, "constant_mse": constant_mse, "skill": skill, "correlation": correlation,
           "steps": int(true.size)}
    if events is not None:
        out["events"] = int(events.sum())
        out["event_mse"] = float(np.mean((predicted[events] - true[events]) ** 2)) if events.any() else float("nan")
        out["event_constant_mse"] = float(np.mean((constant - true[events]) ** 2)) if events.any() else float("nan")
    if time_only is not None:
        out["time_only_mse"] = float(np.mean((np.asarray(time_only) - true) ** 2))
    return out
