"""The front door's notebook index: each notebook, the thesis section it follows, what it shows,
its committed run as its last cell stamped it (:mod:`wmthesis.stamp`: minutes, trained here
or from the shipped runs, date), and its time from scratch: the measured first runs of the runs
its numbers come from (:data:`TRAINS`), summed. ``python -m wmthesis summary`` writes it
into the README between :data:`BEGIN` and :data:`END`, so no time in it is typed by hand."""
from __future__ import annotations

import json
from pathlib import Path

from wmthesis.declarations import NAMES
from wmthesis.runs import first_run_seconds, read_json
from wmthesis.stamp import CHECKOUT, read_stamp
from wmthesis.utils import data_dir

BEGIN, END = "<!-- notebooks: written by `python -m wmthesis summary` -->", "<!-- end of notebooks -->"
# notebook -> (thesis section, what it shows)
SHOWS = {
    "00_environments": ("5.1", "the games, their preprocessing, the episode store"),
    "01_sokoban_world_models": ("5.3.1-5.3.3", "VAE reconstructions (Fig. 54), memory rollouts (Fig. 55), grid states, "
                                               "auxiliary heads, as numbers"),
    "02_boxing_world_models": ("5.4.1", "Fig. 56 and 57, every seed's CMA-ES curve, the score over seeds, the shipped "
                                        "agent playing and dreaming beside the game"),
    "03_boxing_world_models_alphazero": ("5.4.2", "MCTS in the memory: self-play, why the thesis's version fails, the "
                                                  "variants side by side"),
    "04_planet_sokoban": ("5.5.1", "PlaNet's open-loop rollouts on Sokoban (Fig. 58)"),
    "05_planet_boxing": ("5.6.1-5.6.4", "the model study (Fig. 59, 510) measured on held-out bouts; the tuned agent's "
                                        "bouts; its budget beside the thesis's"),
    "06_kl_scale_free_nats_search": ("5.6.3-5.6.5", "the random search over KL scale and free nats (optuna)"),
    "07_sokoban_search": ("beyond (ch. 1)", "Sokoban solved by search in a learned model: Boxoban over seeds, the levers, "
                                            "failures as pictures"),
    "08_planet_freeway": ("5.6.5-5.6.6", "Fig. 511 from the shipped agent, its value variants, the perfect-model ceiling"),
    "09_planet_boxing_value": ("beyond", "a learned value on PlaNet's frozen Boxing model: its rounds, over seeds"),
    "10_planet_value_planner": ("beyond", "CEM with that value at the end of its horizon, over seeds"),
    "11_planning_budget": ("beyond (ch. 1)", "score against search budget: Sokoban's search, MCTS and CEM on Boxing, each "
                                             "without search and under growing budgets"),
}

# notebook -> the runs its numbers come from and the runs they build on, each to be trained from
# nothing (``quick``): (experiment, its variants (None: the default), seeds); those of TRAINS_HERE
# train as they run (their committed run is their time from scratch), and the others train nothing
TRAINS_HERE: tuple[str, ...] = ()
TRAINS = {
    "01_sokoban_world_models": ((NAMES.sokoban_wm, (None,), (0,)),),
    "04_planet_sokoban": ((NAMES.planet_sokoban, ("unchanged",), (0,)),),
    "02_boxing_world_models": ((NAMES.boxing_wm, ("separable-64",), range(10)),),
    "03_boxing_world_models_alphazero": ((NAMES.boxing_wm_alphazero, ("own-memory", "own-reward"), (0,)),
                                         (NAMES.boxing_wm, ("separable-64",), (0,))),
    "05_planet_boxing": ((NAMES.planet_boxing_study, (None,), (0,)), (NAMES.planet_boxing_agent, (None,), (0,))),
    "06_kl_scale_free_nats_search": ((NAMES.planet_boxing_search, (None,), (0,)),),  # its trials, the confirmation apart
    "07_sokoban_search": ((NAMES.sokoban_search, (None,), (0, 1, 2)),),  # with the Boxoban report levels' search
    "08_planet_freeway": ((NAMES.planet_freeway, ("freeway-tuned", "freeway-adam", "freeway-explore", "long-horizon"), (0,)),
                          (NAMES.planet_freeway_value, (None, "td", "horizon-12", "freeway-adam", "adam-td", "adam-log"), (0,))),
    "09_planet_boxing_value": ((NAMES.planet_boxing_value, ("scored-rounds",), (0,)),
                               (NAMES.planet_boxing_value, ("rounds-10",), (1, 2)),
                               (NAMES.planet_boxing_agent, (None,), (0, 1, 2))),
    "10_planet_value_planner": ((NAMES.planet_boxing_value, ("lean-value-rewards-0.7", "lean"), (0, 1, 2)),
                                (NAMES.planet_boxing_agent, (None,), (0, 1, 2))),
    "11_planning_budget": ((NAMES.sokoban_search, (None,), (0, 1, 2)), (NAMES.boxing_wm_alphazero, ("own-memory",), (0, 1, 2)),
                           (NAMES.boxing_wm, ("separable-64",), (0, 1, 2)),
                           (NAMES.planet_boxing_value, ("lean-value-rewards-0.7",), (0, 1, 2)),
                           (NAMES.planet_boxing_agent, (None,), (0, 1, 2))),
}
UNTIMED = {"06_kl_scale_free_nats_search": "its confirmation runs", "11_planning_budget": "the curves' own bouts and levels"}


def run_seconds(experiment: str, variant: str | None, seed: int, profile: str = "quick",
                data: Path | None = None) -> float | None:
    """A committed run's measured time from scratch: its first run's wall seconds
    (``first_run_wall_seconds``, else ``wall_seconds``; a Sokoban agent that ships with its report
    alone: the report's ``training_wall_seconds``), with a Sokoban agent's search on the Boxoban
    report levels added (each kind's seconds a level x levels); None where it has not run. ``data``:
    the data folder (default :func:`~wmthesis.utils.data_dir`'s)."""
    from wmthesis.experiments import VARIANTS  # the registries: loaded when the index is written

    folder = VARIANTS[experiment].folder_name(variant) if experiment in VARIANTS else None
    where = Path(data or data_dir()) / "results" / experiment / f"{profile}-seed{seed}" / (folder or "")
    first, reports = first_run_seconds(where / "metrics.json", None), [read_json(p) for p in sorted(where.glob("boxoban-report-*.json"))]
    if first is None and not reports:
        return None
    seconds = first if first is not None else float(reports[0]["training_wall_seconds"])
    return seconds + sum(float(r["seconds_per_level"]) * int(report["levels"]) for report in reports
                         for r in report["rows"].values())


def scratch(name: str, data: Path | None = None) -> dict | None:
    """Notebook ``name``'s time from scratch: ``seconds`` (its :data:`TRAINS` runs' measured
    times, summed), ``runs`` (how many were measured),
    ``missing`` (those not run yet) and ``untimed`` (what it plays beyond them, not timed);
    None for a notebook that trains here (its committed run is its time from scratch)."""
    if name not in TRAINS:
        return None
    found = {(e, v, s): run_seconds(e, v, s, data=data) for e, variants, seeds in TRAINS[name]
             for v in variants for s in seeds}
    seconds = [t for t in found.values() if t is not None]
    return {"seconds": sum(seconds), "runs": len(seconds), "missing": [k for k, t in found.items() if t is None],
            "untimed": UNTIMED.get(name)}


def notebook_stamp(path: Path) -> dict | None:
    """The stamp the last code cell of the notebook at ``path`` printed (None: not stamped yet)."""
    cells = [c for c in json.loads(Path(path).read_text())["cells"] if c["cell_type"] == "code"]
    if not cells:
        return None
    texts = []
    for output in cells[-1].get("outputs", []):
        texts.append("".join(output.get("text", "")))
        texts.append("".join(output.get("data", {}).get("text/plain", "")))
    return read_stamp("\n".join(texts))


def notebook_rows(folder: Path = CHECKOUT / "notebooks", data: Path | None = None) -> list[dict]:
    """A row per notebook in ``folder`` (sorted): ``name``, ``section``, ``shows``, ``stamp`` and
    ``scratch`` (:func:`scratch`, from the runs under the data folder ``data``, default
    :func:`~wmthesis.utils.data_dir`'s).
    A notebook without an entry in :data:`SHOWS` raises ValueError naming it."""
    rows = []
    for path in sorted(Path(folder).glob("*.ipynb")):
        if path.stem not in SHOWS:
            raise ValueError(f"{path.name}: not in wmthesis.notebook_index.SHOWS; say what it shows there")
        section, shows = SHOWS[path.stem]
        rows.append({"name": path.stem, "section": section, "shows": shows, "stamp": notebook_stamp(path),
                     "scratch": scratch(path.stem, data)})
    return rows


def _committed_run(stamp: dict | None) -> str:
    if stamp is None:
        return "awaiting a re-run on today's code"
    how = {"trained here": ", trained here", "from shipped runs": " from the shipped runs"}.get(stamp["how"], "")
    return f"{max(1, round(stamp['seconds'] / 60))} min{how}, {stamp['profile']}, {stamp['date']}"


def _scratch(row: dict) -> str:
    """The from-scratch cell: hours (minutes under two hours) of measured runs, what is not run yet
    or not timed; the committed run's own time for a notebook that trains here."""
    found = row["scratch"]
    if found is None:
        return "its committed run (it trains as it runs)" if row["name"] in TRAINS_HERE else "nothing to train"
    minutes = found["seconds"] / 60
    text = f"{minutes / 60:.1f} h" if minutes >= 120 else f"{minutes:.0f} min"
    text += f" over {found['runs']} runs" if found["runs"] > 1 else ""
    if found["missing"]:
        text += f", {len(found['missing'])} not run yet"
    return text + (f", {found['untimed']} not timed" if found["untimed"] else "")


def notebook_table(rows: list[dict]) -> str:
    """The index as markdown."""
    lines = ["| notebook | thesis | what it shows | its committed run (2-core CPU) | from scratch (measured runs summed) |",
             "|---|---|---|---|---|"]
    lines += [f"| `{r['name']}` | {r['section']} | {r['shows']} | {_committed_run(r['stamp'])} | {_scratch(r)} |"
              for r in rows]
    return "\n".join(lines)


__all__ = ["BEGIN", "END", "SHOWS", "TRAINS", "TRAINS_HERE", "UNTIMED", "run_seconds", "scratch",
           "notebook_stamp", "notebook_rows", "notebook_table"]
