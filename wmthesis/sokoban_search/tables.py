"""The Sokoban search agent's results as tables: the targets with what one run measured,
the Boxoban table beside the published agents, and the levers and report evaluations over seeds
(read from the run store, ``data/results/sokoban-search/PROFILE-seedS/``)."""
from __future__ import annotations

import numpy as np

from wmthesis.config import for_profile, profile_name
from wmthesis.declarations import NAMES
from wmthesis.envs.boxoban import BOXOBAN_SPLITS
from wmthesis.metrics import aggregate
from wmthesis.references import BOXOBAN_PUBLISHED
from wmthesis.runs import read_json, results_folder
from wmthesis.sokoban_search.config import SokobanSearchConfig
from wmthesis.sokoban_search.evaluation import THESIS_ROW, thesis_row
from wmthesis.sokoban_search.report import BOXOBAN_AGENTS, evaluation_record
from wmthesis.utils import data_dir


# The experiment's targets in quick: (variant, inputs, lowest solve rate); fewer than 1M env steps. (Its
# target from grid states, met in its time, went with the grid run: the experiment trains from pixels.)
SOKOBAN_SEARCH_TARGETS = (("sokoban-small", "pixels", 0.95), ("sokoban", "pixels", 0.90))

MAX_ENV_STEPS = 1_000_000

# The model's targets on unseen levels: one-step and 30-step open-loop exactness; no player vanishes.
MODEL_TARGETS = {"one step": 0.995, "open loop +30": 0.95}

def _verdict(met: bool, shortfall: str = "") -> str:
    """A target's last column: "met", or "missed" with the shortfall where there is one."""
    return "met" if met else f"missed by {shortfall}" if shortfall else "missed"

def _env_steps_row(steps: int, prefix: str = "") -> list:
    """The data-budget target's row: fewer than :data:`MAX_ENV_STEPS` environment steps."""
    return [f"{prefix}fewer than {MAX_ENV_STEPS:,} environment steps", f"{steps:,}", _verdict(steps < MAX_ENV_STEPS)]

def target_rows(metrics: dict) -> list[list]:
    """Each target of the search's first evaluation with the measured value and whether it is met."""
    rows = []
    for variant, inputs, lowest in SOKOBAN_SEARCH_TARGETS:
        rate = metrics["tables"].get(variant, {}).get(f"agent, learned model ({inputs})", {}).get("solve_rate")
        if rate is not None:
            rows.append([f"{variant} from {inputs}: at least {lowest:.0%} solved", f"{rate:.1%}",
                         _verdict(rate >= lowest, f"{lowest - rate:.1%}")])
    for inputs, steps in metrics["env_steps"].items():
        rows.append(_env_steps_row(steps, f"{inputs}: "))
    for variant, by_inputs in metrics.get("accuracy", {}).items():
        for inputs, measures in by_inputs.items():
            loop = {int(k): v for k, v in measures["open_loop"].items()}[30]  # int keys, or str from JSON
            exact = {"one step": (measures["one_step"]["exact"], f"{measures['one_step']['transitions']:,} transitions"),
                     "open loop +30": (loop.get("exact"), f"{loop['sequences']} plans")}  # none: no plan that long
            for name, lowest in MODEL_TARGETS.items():
                value, over = exact[name]
                rows.append([f"{variant} from {inputs}, model exact {name}: at least {lowest:.1%}",
                             f"{value:.2%} ({over})" if value is not None else f"({over})",
                             "not measured" if value is None else
                             _verdict(value >= lowest, f"{lowest - value:.2%}")])
            vanished = max(measures["one_step"]["player_vanished"], loop.get("player_vanished", 0.0))
            rows.append([f"{variant} from {inputs}: no player vanishes", f"{vanished:.2%}",
                         _verdict(vanished == 0)])
    training, evaluation = metrics.get("training_wall_seconds"), metrics.get("evaluation_wall_seconds")
    if training is not None and evaluation is not None:  # however the run was trained: its stages' own times
        seconds, measured = training + evaluation, "training's stages + evaluation"
    else:
        seconds, measured = metrics.get("first_run_wall_seconds"), "first run"
    if seconds is not None:
        rows.append([f"the whole experiment within {NOTEBOOK_MINUTES} minutes ({measured})", f"{seconds / 60:.1f} min",
                     _verdict(seconds <= NOTEBOOK_MINUTES * 60, f"{seconds / 60 - NOTEBOOK_MINUTES:.1f} min")])
    return rows

# The targets in quick, from pixels: each report kind's lowest solve rate (over 3 seeds in
# the closing figures; a run's metrics give one), seconds a level on one core, the notebook's minutes.
BOXOBAN_TARGETS = {"unfiltered": 0.99, "medium": 0.85}
MAX_SECONDS_PER_LEVEL, NOTEBOOK_MINUTES = 5.0, 75

def boxoban_target_rows(metrics: dict) -> list[list]:
    """Each target of the Boxoban evaluation that one run measures, with the measured value and whether it is
    met: the pixel agent's solve rate on each report kind, its seconds a level (each level on one
    core), its environment steps, and the training stages with the evaluation against the
    notebook's 75 minutes."""
    rows, agent = [], BOXOBAN_AGENTS["pixels"]
    tables = metrics["boxoban"]["tables"]
    for kind, lowest in BOXOBAN_TARGETS.items():
        row = tables[kind][agent]
        rows.append([f"Boxoban {kind} from pixels: at least {lowest:.0%} (this seed, {row['levels']} report levels)",
                     f"{row['solve_rate']:.1%}",
                     _verdict(row["solve_rate"] >= lowest, f"{lowest - row['solve_rate']:.1%}")])
    seconds = float(np.mean([tables[kind][agent]["seconds_per_level"] for kind in BOXOBAN_TARGETS]))
    rows.append([f"seconds a level on one core, both kinds: at most {MAX_SECONDS_PER_LEVEL:.0f}", f"{seconds:.2f} s",
                 _verdict(seconds <= MAX_SECONDS_PER_LEVEL, f"{seconds - MAX_SECONDS_PER_LEVEL:.2f} s")])
    rows.append(_env_steps_row(metrics["env_steps"]["pixels"]))
    training, evaluation = metrics.get("training_wall_seconds"), metrics.get("evaluation_wall_seconds")
    if training is not None and evaluation is not None:
        minutes = (training + evaluation) / 60
        rows.append([f"a quick seed trained here within {NOTEBOOK_MINUTES} minutes (training's stages + evaluation)",
                     f"{minutes:.1f} min", _verdict(minutes <= NOTEBOOK_MINUTES, f"{minutes - NOTEBOOK_MINUTES:.1f} min")])
    return rows

def boxoban_rows(metrics: dict) -> list[list]:
    """The Boxoban table of a run's metrics beside the published agents: one row per agent,
    (agent, unfiltered %, medium %, levels, data, source)."""
    tables, rows = metrics["boxoban"]["tables"], []
    steps = metrics["env_steps"]
    data = {title: steps.get("pixels") for title in BOXOBAN_AGENTS.values()}
    for title in tables["unfiltered"]:
        if title == THESIS_ROW:  # a run's own row or not (runs written before gave it 0): it never played Boxoban
            rows.append([title, *(thesis_row(k).get("note", "") for k in ("unfiltered", "medium")), "", "", ""])
            continue
        measured = {kind: tables[kind][title] for kind in tables}
        levels = {m.get("levels") for m in measured.values()} - {None}
        rows.append([title, *(f"{100 * measured[k]['solve_rate']:.1f}" for k in ("unfiltered", "medium")),
                     ", ".join(map(str, sorted(levels))), f"{data[title]:,} env steps" if data.get(title) else "",
                     "this run, " + ", ".join(f"{k}: {BOXOBAN_SPLITS['report'][k]}" for k in tables)])
    return rows + [list(row[:3]) + ["", *row[3:]] for row in BOXOBAN_PUBLISHED]

def lever_rows(profile: str | None = None, seed: int = 0) -> list[list]:
    """The levers measured so far on the validation files (every ``validation-*.json`` that
    :func:`validate` wrote, or kept from an earlier baseline under its own name): (lever, its
    changes, unfiltered %, medium %, levels, nodes per level, seconds per level, environment
    steps), the baseline first."""
    folder = results_folder(NAMES.sokoban_search, profile_name(profile), seed)
    found = [result for result in map(read_json, folder.glob("validation-*.json")) if result and "lever" in result]
    found.sort(key=lambda result: (result["lever"] != "baseline", result["lever"]))
    rows = []
    for result in found:
        measured = result["rows"]
        rows.append([result["lever"], ", ".join(f"{k}={v}" for k, v in result["changes"].items()) or "(quick as it is)",
                     *(f"{100 * measured[k]['solve_rate']:.1f}" for k in ("unfiltered", "medium")),
                     measured["unfiltered"]["levels"],
                     f"{np.mean([m['nodes_per_level'] for m in measured.values()]):,.0f}",
                     f"{np.mean([m['seconds_per_level'] for m in measured.values()]):.2f}", f"{result['env_steps']:,}"])
    return rows

def lever_seed_rows(lever: str = "baseline", profile: str | None = None) -> list[list]:
    """One lever on the validation files over the seeds measured so far (each seed's
    ``validation-LEVER.json``): see :func:`_seed_rows`."""
    return _seed_rows(f"validation-{lever}.json", profile, lambda result: result.get("lever") == lever)

def report_seed_rows(levels: int = 1000, profile: str | None = None) -> list[list]:
    """The closing figures over the seeds measured so far: each seed's :func:`evaluate_report` on
    the first ``levels`` levels of each report file (``boxoban-report-LEVELS.json``), searched as
    the profile's agent searches today (a figure of another search is left out); see
    :func:`_seed_rows`."""
    search = evaluation_record(for_profile(SokobanSearchConfig, profile_name(profile), inputs="pixels"))
    return _seed_rows(f"boxoban-report-{levels}.json", profile,
                      lambda result: result.get("levels") == levels and result.get("search") == search)

def _seed_rows(name: str, profile: str | None, accept) -> list[list]:
    """The results named ``name`` of every seed of a profile (those ``accept`` takes): a row per
    seed (seed, unfiltered %, medium %, levels, nodes per level, seconds per level, environment
    steps), then the mean, the sample standard deviation and the 95% Student-t interval of the
    mean over the seeds, clipped to 0-100% (:func:`~wmthesis.metrics.aggregate`)."""

    root, found = data_dir("results", NAMES.sokoban_search), []
    for path in sorted(root.glob(f"{profile_name(profile)}-seed*/{name}")):
        result = read_json(path)
        if result and accept(result):
            found.append(result)
    found.sort(key=lambda result: result["seed"])
    kinds = ("unfiltered", "medium")
    rates = np.array([[100 * r["rows"][k]["solve_rate"] for k in kinds] for r in found])
    rows = [[r["seed"], *(f"{x:.1f}" for x in rate), r["rows"]["unfiltered"]["levels"],
             f"{np.mean([r['rows'][k]['nodes_per_level'] for k in kinds]):,.0f}",
             f"{np.mean([r['rows'][k]['seconds_per_level'] for k in kinds]):.2f}", f"{r['env_steps']:,}"]
            for r, rate in zip(found, rates)]
    if len(found) > 1:
        spread = [aggregate(rates[:, i], (0.0, 100.0)) for i in range(len(kinds))]
        rows.append([f"mean ± std [95% CI], {len(found)} seeds",
                     *(f"{a['mean']:.1f} ± {a['std']:.1f} [{a['ci_low']:.1f}, {a['ci_high']:.1f}]" for a in spread),
                     "", "", "", ""])
    return rows


def solved_line(name: str, rows: dict) -> str:
    """Evaluation rows (kind -> solved, levels, rate, nodes and seconds a level) as one line:
    ``name: kind solved/levels (rate%), nodes and seconds a level; ...``."""
    return f"{name}: " + "; ".join(
        f"{kind} {row['solved']}/{row['levels']} ({100 * row['solve_rate']:.1f}%), "
        f"{row['nodes_per_level']:,.0f} nodes and {row['seconds_per_level']:.1f} s a level"
        for kind, row in rows.items())


__all__ = ["solved_line", "SOKOBAN_SEARCH_TARGETS", "MAX_ENV_STEPS", "MODEL_TARGETS", "BOXOBAN_TARGETS", "target_rows",
           "boxoban_target_rows", "boxoban_rows", "lever_rows", "lever_seed_rows", "report_seed_rows"]
