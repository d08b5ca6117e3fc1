"""Expert iteration: random play, then rounds of play by the search agent, each round training
the model on everything seen and the value on every level solved (5.3.3's suggestion: "an
iterative approach to gathering data could solve this").

A run lives in one folder: ``experience.h5`` (:class:`~wmthesis.sokoban_search.experience.Experience`)
and ``state.pt``, written after random play and after every round (the model's and the value's
weights, the optimisers, the round reached and the history). Re-running resumes after the last
finished round; rows of a round that was cut off are dropped first, so the result is the same.
Within a round, each part of its levels is kept as it finishes (``round-N/part-P.pkl``, removed once
the round is saved): a round cut off in its play replays only the parts it had not finished.
Each stage's record in the history holds its wall time (``wall_seconds``: play and fits).

The value starts afresh each round, trained on every level solved so far (carried over from round
to round, as the model is, it stays fitted to the early rounds' short solutions). Beside the solved
levels' states, the value learns from the last round's searches (``cfg.backups``: states each
search expanded, with their backed-up steps to go,
:func:`~wmthesis.sokoban_search.heuristic.backed_up`). The measurements behind both choices:
``docs/findings/sokoban-search.md``.
"""
from __future__ import annotations

import dataclasses
import math
import pickle
import shutil
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.envs.sokoban import CELL_NAMES
from wmthesis.runs import atomic_path, write_json
from wmthesis.sokoban_search.agent import SearchAgent, level_seeds, random_play, variant_options
from wmthesis.sokoban_search.cells import CellCoder, GRID, GridInputs, PixelInputs, fit_coder, render_cells
from wmthesis.sokoban_search.config import SokobanSearchConfig
from wmthesis.sokoban_search.evaluation import play_levels
from wmthesis.sokoban_search.experience import Experience
from wmthesis.sokoban_search.heuristic import Heuristic, steps_to_go, turned
from wmthesis.sokoban_search.model import SokobanModel
from wmthesis.sokoban_search.policy import Policy, turned_actions
from wmthesis.training import check_same_config, gradient_step, with_added_defaults
from wmthesis.utils import check_choice, device, half_precision, parallel_calls, read_pickle

N_ACTIONS = 8
STATE_VERSION = 3  # 2: the model keeps the count changes it has seen; 3: and the boards at ends
INPUTS = ("grid", "pixels")
AFTERWARDS = "policy-afterwards.pt"  # a policy prior fitted on a finished run's solutions


@dataclasses.dataclass
class Run:
    """What a run has learned: ``model``, ``heuristic`` (None before any level was solved),
    ``history`` (one dict per stage: random play, then each round), ``rounds_done``,
    ``inputs``, what the agent sees (grid states, or pixels through a learned
    :class:`~wmthesis.sokoban_search.cells.CellCoder`), and ``policy``, the policy prior (None
    unless the config gives it a weight)."""

    model: SokobanModel
    heuristic: Heuristic | None
    history: list
    rounds_done: int
    inputs: GridInputs = GRID
    policy: Policy | None = None

    def agent(self, cfg: SokobanSearchConfig, model=None, inputs=None, backups: int = 0) -> SearchAgent:
        """The search agent of this run (``model``, ``inputs``: e.g. the simulator on grid states;
        ``backups``: states each search keeps with their backed-up labels, as in the rounds)."""
        heuristic = self.heuristic.estimate if self.heuristic is not None else None
        prior = self.policy.log_probs if self.policy is not None and cfg.prior_weight > 0 else None
        return SearchAgent(model if model is not None else self.model, inputs=inputs or self.inputs,
                           heuristic=heuristic, budget=cfg.budget, batch=cfg.batch, weights=cfg.weights,
                           doubt=cfg.doubt, replans=cfg.replans, prior=prior, prior_weight=cfg.prior_weight,
                           backups=backups, cap=cfg.backup_cap)


def schedule(cfg: SokobanSearchConfig) -> list[tuple[str, int]]:
    """The rounds in order: (variant, round within the variant) for ``cfg.rounds`` per variant."""
    return [(variant, r) for variant in cfg.variants for r in range(cfg.rounds)]


def train_search_agent(folder: str | Path, cfg: SokobanSearchConfig, progress: bool = True) -> Run:
    """Random play, the model trained on it, then every round of :func:`schedule`; resumable."""
    check_choice("inputs", cfg.inputs, INPUTS)
    for variant in cfg.variants:
        variant_options(variant)  # an unknown variant, or Boxoban's valid files, fail here
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    run = load_run(folder, cfg)
    for stale in folder.glob("round-*"):  # parts of a round already saved, or of a run started over
        number = stale.name.removeprefix("round-")
        if number.isdigit() and (run is None or int(number) <= run.rounds_done):
            shutil.rmtree(stale, ignore_errors=True)
    rounds = schedule(cfg)
    with Experience(folder / "experience.h5") as experience:
        if run is None:
            experience.drop_rounds(0)
            run = _random_stage(experience, cfg, progress)
            save_run(folder, run, cfg)
        if run.rounds_done < len(rounds) and experience.count() == 0:  # e.g. a checkpoint copied alone
            raise ValueError(f"{folder / 'state.pt'} is a run stopped after round {run.rounds_done} of "
                             f"{len(rounds)}, and its experience ({folder / 'experience.h5'}) is not there: "
                             f"it cannot resume without it; delete state.pt to train from the start")
        experience.drop_rounds(run.rounds_done + 1)
        for index in range(run.rounds_done, len(rounds)):
            _round(run, experience, cfg, index + 1, *rounds[index], progress, folder / f"round-{index + 1}")
            save_run(folder, run, cfg)
            shutil.rmtree(folder / f"round-{index + 1}", ignore_errors=True)  # its parts are in the run now
    return run


def _random_stage(experience: Experience, cfg: SokobanSearchConfig, progress: bool) -> Run:
    started = time.perf_counter()
    played = [random_play(variant, cfg.seed * 100 + v, cfg.random_levels) for v, variant in enumerate(cfg.variants)]
    inputs = GRID
    if cfg.inputs == "pixels":  # the codes are learned from random play's frames first
        frames = [render_cells(rows["states"][::20], cfg.tile_size) for rows in played]
        inputs = PixelInputs(fit_coder(frames, cfg.tile_size, cfg.codes, cfg.seed))
    for rows in played:
        experience.add("transitions", 0, **{**rows, "states": inputs.from_grid(rows["states"]),
                                            "next_states": inputs.from_grid(rows["next_states"])})
    steps = sum(len(rows["actions"]) for rows in played)
    rewards = np.unique(np.concatenate([g["rewards"] for g in experience.arrays("transitions").values()]))
    torch.manual_seed(cfg.seed)
    model = SokobanModel(n_codes(cfg), N_ACTIONS, rewards, cfg.channels, cfg.blocks).to(device())
    losses = fit_model(model, experience, cfg, cfg.model_updates, np.random.default_rng([cfg.seed, 0]),
                       "model (random play)", progress)
    record = dict(round=0, variant="random play", env_steps=steps, levels=cfg.random_levels * len(cfg.variants),
                  solved=None, model_loss=losses, exactness=held_out_exactness(model, cfg, inputs),
                  wall_seconds=time.perf_counter() - started)
    return Run(model, None, [record], 0, inputs)


def n_codes(cfg: SokobanSearchConfig) -> int:
    """Codes per cell: the board's cell types (grid), or the coder's codebook (pixels)."""
    return cfg.codes if cfg.inputs == "pixels" else len(CELL_NAMES)


ROUND_PARTS = 8  # a round's levels in parts, played two at a time on 2 cores (a bar over the parts)


def play_in_parts(run: Run, cfg: SokobanSearchConfig, variant: str, seeds: list[int], progress: bool = True,
                  kept: Path | None = None) -> list:
    """The agent of ``run`` searching as ``cfg`` says on the levels of ``variant`` that ``seeds``
    generate (:func:`~wmthesis.sokoban_search.evaluation.play_levels`): one
    :class:`~wmthesis.sokoban_search.agent.Play` per seed, in order. The levels are played in
    :data:`ROUND_PARTS` parts in parallel processes (:func:`~wmthesis.utils.parallel_calls`);
    each level is played as it would be alone. With a folder ``kept``, each part is saved there
    as it finishes, and a part saved there for the same levels is read back, not played again."""
    parts = [seeds[p::ROUND_PARTS] for p in range(min(ROUND_PARTS, len(seeds)))]
    played = [_kept_part(kept, p, part) for p, part in enumerate(parts)]
    missing = [p for p, plays in enumerate(played) if plays is None]

    def keep(index: int, plays: list) -> None:
        played[missing[index]] = plays
        if kept is not None:
            kept.mkdir(parents=True, exist_ok=True)
            with atomic_path(kept / f"part-{missing[index]}.pkl") as tmp:
                Path(tmp).write_bytes(pickle.dumps({"seeds": parts[missing[index]], "plays": plays}))

    parallel_calls([(_play_part, run, cfg, variant, parts[p]) for p in missing], progress, keep)
    return [played[i % len(parts)][i // len(parts)] for i in range(len(seeds))]


def _kept_part(kept: Path | None, index: int, seeds: list[int]) -> list | None:
    """The plays of part ``index`` saved in ``kept`` for these ``seeds``, or None (none saved, or
    saved for other levels, or unreadable: then it is played again)."""
    path = None if kept is None else kept / f"part-{index}.pkl"
    if path is None or not path.exists():
        return None
    try:
        saved = read_pickle(path)
    except ValueError:  # corrupt (copied or edited by hand): play the part again
        return None
    return saved["plays"] if isinstance(saved, dict) and saved.get("seeds") == list(seeds) else None


def _play_part(run: Run, cfg: SokobanSearchConfig, variant: str, seeds: list[int]) -> list:
    return play_levels(run.agent(cfg, backups=cfg.backups), variant, seeds, progress=False)


def _round(run: Run, experience: Experience, cfg: SokobanSearchConfig, number: int, variant: str, r: int,
           progress: bool, kept: Path | None = None) -> None:
    """Round ``number``: play levels (each part kept in the folder ``kept`` as it finishes, see
    :func:`play_in_parts`), keep what was seen, train the model and the value."""
    started = time.perf_counter()
    expert = dataclasses.replace(cfg, budget=cfg.round_budget or cfg.budget)  # the expert in training
    plays = play_in_parts(run, expert, variant, level_seeds(cfg.seed, 1 + number, cfg.levels_per_round), progress,
                          kept)
    for play in plays:
        experience.add("transitions", number, **play.transitions)
        if play.solved:
            states = play.transitions["states"]
            experience.add("to_go", number, states=states, labels=steps_to_go(states))
            experience.add("solutions", number, states=states, actions=play.transitions["actions"])
        if len(play.backed_up.get("labels", ())):
            experience.add("backed_up", number, **play.backed_up)
    rng = np.random.default_rng([cfg.seed, number])
    losses = fit_model(run.model, experience, cfg, cfg.round_updates, rng, f"model (round {number})", progress)
    if experience.count("to_go"):  # a fresh value each round (see the module's docstring)
        torch.manual_seed(cfg.seed + number)
        run.heuristic = Heuristic(n_codes(cfg), cfg.value_channels, cfg.value_blocks).to(device())
        value_error = fit_heuristic(run.heuristic, experience, cfg, rng, f"value (round {number})", progress)
    else:
        value_error = None
    policy_accuracy = None
    if cfg.prior_weight > 0 and experience.count("solutions"):  # a fresh policy prior each round, as the value
        torch.manual_seed(cfg.seed + number)
        run.policy = Policy(n_codes(cfg), N_ACTIONS, cfg.value_channels, cfg.value_blocks).to(device())
        policy_accuracy = fit_policy(run.policy, experience, cfg, rng, f"policy (round {number})", progress)
    run.history.append(dict(round=number, variant=variant, env_steps=int(sum(len(p.actions) for p in plays)),
                            levels=len(plays), solved=float(np.mean([p.solved for p in plays])),
                            expanded=float(np.mean([p.expanded for p in plays])),
                            seconds_per_level=float(np.mean([p.seconds for p in plays])),
                            model_loss=losses, value_error=value_error,
                            **({"policy_accuracy": policy_accuracy} if policy_accuracy is not None else {}),
                            exactness=held_out_exactness(run.model, cfg, run.inputs),
                            wall_seconds=time.perf_counter() - started))
    run.rounds_done = number


# ---------------------------------------------------------------------------- training

def training_batches(groups: dict, batch_size: int, rng: np.random.Generator, special=()):
    """Endless batches (dicts of tensors) from ``groups`` ({"HxW": arrays}): a group picked in
    proportion to its rows, then rows uniformly, except that for each (fraction, marks) of
    ``special`` that fraction of the batch is drawn among the rows ``marks(group)`` marks."""
    keys = sorted(groups)
    sizes = np.array([len(groups[k]["states"]) for k in keys], dtype=np.float64)
    special = [(fraction, marks) for fraction, marks in special if fraction > 0]
    if sum(fraction for fraction, _ in special) > 1:
        raise ValueError(f"the special fractions of a batch add up to more than 1: {[f for f, _ in special]}")
    dev = device()
    while True:
        group = groups[keys[rng.choice(len(keys), p=sizes / sizes.sum())]]
        n = len(group["states"])
        picked = rng.integers(n, size=batch_size)
        start = 0
        for fraction, marks in special:
            rows = np.flatnonzero(marks(group))
            k = int(round(fraction * batch_size)) if len(rows) else 0
            picked[start:start + k] = rng.choice(rows, size=k) if k else picked[start:start + k]
            start += k
        yield {name: torch.as_tensor(values[picked], device=dev) for name, values in group.items() if name != "rounds"}


def _optimise(module, losses, batches, updates: int, lr: float, desc: str, progress: bool) -> dict:
    """``updates`` Adam steps with a cosine decay from ``lr`` to ``lr / 10`` (in bfloat16 where
    the hardware has it, :func:`~wmthesis.utils.half_precision`: on this project's CPU 600
    updates of the model took 63% of the time and reached the same exactness); the mean of each
    loss term over the last tenth of the updates."""
    optimiser = torch.optim.Adam(module.parameters(), lr)
    tail, kept = max(1, updates // 10), {}
    module.train()
    for update in tqdm(range(1, updates + 1), desc=desc, disable=not progress, leave=False):
        for group in optimiser.param_groups:
            group["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * (update - 1) / updates)))
        with half_precision(device()):
            terms = losses(next(batches))
        gradient_step(desc, update, terms, optimiser, module.parameters(), clip_norm=1.0,
                      kept="the last finished round is kept in state.pt")
        if update > updates - tail:
            for key, value in terms.items():
                kept[key] = kept.get(key, 0.0) + float(value.detach()) / tail
    return kept


def fit_model(model: SokobanModel, experience: Experience, cfg: SokobanSearchConfig, updates: int,
              rng: np.random.Generator, desc: str = "model", progress: bool = True) -> dict:
    """Train ``model`` on every transition of ``experience`` (and let it see their count changes
    and the boards at their ends)."""
    groups = experience.arrays("transitions")
    for group in groups.values():
        model.see_changes(group["states"], group["next_states"])
        model.see_ends(group["next_states"][group["dones"]])
    values, counts = np.unique(np.concatenate([g["rewards"] for g in groups.values()]), return_counts=True)
    commonest = values[counts.argmax()]  # the step penalty; the rest are events worth oversampling
    batches = training_batches(groups, cfg.batch_size, rng, [(cfg.event_fraction, lambda g: g["rewards"] != commonest),
                                                     (cfg.agent_fraction, lambda g: g["rounds"] > 0)])
    return _optimise(model, model.losses, batches, updates, cfg.lr, desc, progress)


def fit_heuristic(heuristic: Heuristic, experience: Experience, cfg: SokobanSearchConfig,
                  rng: np.random.Generator, desc: str = "value", progress: bool = True) -> float:
    """Train the value on every labelled state of the solved levels, and, if the run keeps
    backed-up states (``cfg.backups``), on the last round's: ``cfg.backup_fraction`` of each
    batch (each batch in a random one of the board's symmetries if ``cfg.value_symmetries``);
    returns its mean absolute error (steps)."""
    groups = {k: {"states": g["states"], "to_go": g["labels"]} for k, g in experience.arrays("to_go").items()}
    backed = last_round(experience.arrays("backed_up")) if cfg.backups else {}
    share = int(round(cfg.backup_fraction * cfg.batch_size)) if backed else 0
    batches = training_batches(groups, cfg.batch_size - share, rng)
    if share:
        batches = with_backed_up(batches, backed, share, rng)
    if cfg.value_symmetries:
        batches = ({**batch, "states": turned(batch["states"], int(rng.integers(4)), bool(rng.integers(2)))}
                   for batch in batches)
    kept = _optimise(heuristic, heuristic.losses, batches, cfg.value_updates, cfg.lr, desc, progress)
    return kept["abs_error"]


def fit_policy(policy: Policy, experience: Experience, cfg: SokobanSearchConfig,
               rng: np.random.Generator, desc: str = "policy", progress: bool = True) -> float:
    """Train the policy prior on every (state, action) of the levels solved so far, ``value_updates``
    updates (each batch in a random one of the board's symmetries, states and actions turned
    together, if ``cfg.value_symmetries``); returns how often its likeliest action is the one
    taken, over the last tenth of the updates."""
    groups = experience.solutions()
    batches = training_batches(groups, cfg.batch_size, rng)
    if cfg.value_symmetries:
        batches = (_turned_batch(batch, int(rng.integers(4)), bool(rng.integers(2))) for batch in batches)
    return _optimise(policy, policy.losses, batches, cfg.value_updates, cfg.lr, desc, progress)["accuracy"]


def policy_afterwards(folder: str | Path, run: Run, cfg: SokobanSearchConfig, progress: bool = True) -> Policy:
    """A policy prior for ``run``, the finished run in ``folder`` trained with ``cfg`` (and no
    prior), fitted once on its own solutions (:func:`fit_policy`) and saved as
    ``folder/policy-afterwards.pt``, read from there after. What a prior adds to the search with
    the model and the value as they are, no round played again."""
    path = Path(folder) / AFTERWARDS
    if path.exists():
        policy = Policy(run.model.n_codes, N_ACTIONS, cfg.value_channels, cfg.value_blocks).to(device())
        policy.load_state_dict(torch.load(path, map_location=device()))
        return policy
    torch.manual_seed(cfg.seed + 10_000)  # its first weights, from the run's seed
    policy = Policy(run.model.n_codes, N_ACTIONS, cfg.value_channels, cfg.value_blocks).to(device())
    with Experience(Path(folder) / "experience.h5") as experience:
        if not sum(len(g["actions"]) for g in experience.solutions().values()):
            raise ValueError(f"{folder}: the run solved no level, no policy can be learned from its solutions")
        fit_policy(policy, experience, cfg, np.random.default_rng([cfg.seed, 10_000]), "policy (afterwards)", progress)
    with atomic_path(path) as tmp:
        torch.save(policy.state_dict(), tmp)
    return policy


def last_round(groups: dict) -> dict:
    """``{"HxW": {"states", "to_go"}}``: the rows of the last round in ``groups`` (of ``backed_up``)."""
    last = max((int(g["rounds"].max()) for g in groups.values()), default=None)
    return {k: {"states": g["states"][g["rounds"] == last], "to_go": g["labels"][g["rounds"] == last]}
            for k, g in groups.items() if (g["rounds"] == last).any()}


def with_backed_up(batches, backed: dict, share: int, rng: np.random.Generator):
    """Each batch of ``batches`` with ``share`` rows of ``backed`` ({"HxW": {"states", "to_go"}})
    added, drawn uniformly among those of its board size (none where there are none)."""
    for batch in batches:
        group = backed.get("x".join(str(n) for n in batch["states"].shape[1:]))
        if group is not None:
            picked = rng.integers(len(group["states"]), size=share)
            batch = {k: torch.cat([batch[k], torch.as_tensor(group[k][picked], device=batch[k].device)])
                     for k in batch}
        yield batch


def _turned_batch(batch: dict, quarter_turns: int, mirrored: bool) -> dict:
    return {"states": turned(batch["states"], quarter_turns, mirrored),
            "actions": turned_actions(batch["actions"], quarter_turns, mirrored)}


def held_out_exactness(model: SokobanModel, cfg: SokobanSearchConfig, inputs=GRID, levels: int = 20) -> dict:
    """One-step whole-board exactness on random play of unseen levels, per variant."""
    out = {}
    for v, variant in enumerate(cfg.variants):
        rows = random_play(variant, 10_000 + cfg.seed * 100 + v, levels)
        predicted, _, _ = model.step(inputs.from_grid(rows["states"]), rows["actions"])
        truth = inputs.from_grid(rows["next_states"])
        out[variant] = float((predicted == truth).reshape(len(predicted), -1).all(1).mean())
    return out


# ---------------------------------------------------------------------------- checkpoints

def save_run(folder: Path, run: Run, cfg: SokobanSearchConfig) -> None:
    payload = {"version": STATE_VERSION, "config": dataclasses.asdict(cfg), "model_config": run.model.config(),
               "model": run.model.state_dict(), "rounds_done": run.rounds_done, "history": run.history,
               "heuristic": None if run.heuristic is None else run.heuristic.state_dict(),
               "policy": None if run.policy is None else run.policy.state_dict(),
               "coder": run.inputs.coder.state() if isinstance(run.inputs, PixelInputs) else None}
    with atomic_path(folder / "state.pt") as tmp:
        torch.save(payload, tmp)
    write_json(folder / "history.json", run.history)


EVALUATION_FIELDS = ("eval_budget", "eval_levels")  # read by the evaluation alone, not by training


def _trained_as(config: dict) -> dict:
    """What identifies a trained run in a config dict: every field but :data:`EVALUATION_FIELDS`."""
    return {k: v for k, v in config.items() if k not in EVALUATION_FIELDS}


def evaluation_search(cfg: SokobanSearchConfig) -> SokobanSearchConfig:
    """The config the agent searches with at evaluation: ``eval_budget`` nodes a search where it is set."""
    return dataclasses.replace(cfg, budget=cfg.eval_budget or cfg.budget)


def load_run(folder: str | Path, cfg: SokobanSearchConfig | None = None) -> Run | None:
    """The run saved in ``folder`` (None if there is none); with ``cfg``, refuse one trained with
    another config."""
    path = Path(folder) / "state.pt"
    if not path.exists():
        return None
    try:
        saved = torch.load(path, weights_only=False, map_location=device())
        version = saved["version"]
    except Exception as error:  # a truncated or foreign file
        raise ValueError(f"cannot read {path}: {error}; delete it to start over") from error
    if "format" in saved:  # another family's agent file (they name their form)
        raise ValueError(f"{path} holds a {saved['format']} file (version {version}), not a Sokoban search run's "
                         "state: train it with `python -m wmthesis reproduce sokoban-search`")
    if version != STATE_VERSION:
        raise ValueError(f"{path} has format version {version}, this code reads {STATE_VERSION}")
    if cfg is not None:
        check_same_config(path, _trained_as(with_added_defaults(type(cfg), saved["config"])),
                          _trained_as(dataclasses.asdict(cfg)))
    model = SokobanModel(**saved["model_config"]).to(device())
    model.load_state_dict(saved["model"])
    heuristic = None
    if saved["heuristic"] is not None:
        c = saved["config"]
        heuristic = Heuristic(model.n_codes, c["value_channels"], c["value_blocks"]).to(device())
        heuristic.load_state_dict(saved["heuristic"])
    policy = None
    if saved.get("policy") is not None:  # a policy prior (runs whose config weighs one)
        c = saved["config"]
        policy = Policy(model.n_codes, N_ACTIONS, c["value_channels"], c["value_blocks"]).to(device())
        policy.load_state_dict(saved["policy"])
    inputs = GRID if saved.get("coder") is None else PixelInputs(CellCoder(**saved["coder"]))
    return Run(model, heuristic, saved["history"], saved["rounds_done"], inputs, policy)


__all__ = ["Run", "train_search_agent", "load_run", "save_run", "schedule", "fit_model", "fit_heuristic", "fit_policy",
           "policy_afterwards", "play_in_parts", "evaluation_search", "EVALUATION_FIELDS",
           "held_out_exactness"]
