"""The front door's notebook index: each notebook, the thesis section it follows, what it shows,
and its committed run as its last cell stamped it (:mod:`wmthesis.stamp`: minutes, trained here
or from the shipped runs, date). ``python -m wmthesis summary`` writes it into the README between
:data:`BEGIN` and :data:`END`, so no time in it is typed by hand."""
from __future__ import annotations

import json
from pathlib import Path

from wmthesis.stamp import CHECKOUT, read_stamp

BEGIN, END = "<!-- notebooks: written by `python -m wmthesis summary` -->", "<!-- end of notebooks -->"
# notebook -> (thesis section, what it shows)
SHOWS = {
    "00_environments": ("5.1", "the games, their preprocessing, the episode store"),
    "01_sokoban_world_models": ("5.3.1-5.3.3", "VAE reconstructions (Fig. 54), memory rollouts (Fig. 55), grid states, "
                                               "auxiliary heads, as numbers"),
    "02_boxing_world_models": ("5.4.1", "Fig. 56 and 57, every seed's CMA-ES curve, the score over seeds, the shipped "
                                        "agent playing; the controller evolved in the dream"),
    "03_boxing_world_models_alphazero": ("5.4.2", "MCTS in the memory: self-play, why the thesis's version fails, the "
                                                  "variants side by side"),
    "04_planet_sokoban": ("5.5.1", "PlaNet's open-loop rollouts on Sokoban (Fig. 58)"),
    "05_planet_boxing": ("5.6.1-5.6.4", "the model study (Fig. 59, 510) measured on held-out bouts; the tuned agent's bouts"),
    "06_kl_scale_free_nats_search": ("5.6.3-5.6.5", "the random search over KL scale and free nats (optuna)"),
    "07_sokoban_search": ("beyond (ch. 1)", "Sokoban solved by search in a learned model: Boxoban over seeds, the levers, "
                                            "failures as pictures"),
    "08_planet_freeway": ("5.6.5-5.6.6", "the tuned Freeway agent, its value variants, the perfect-model ceiling"),
    "09_planet_boxing_value": ("beyond", "a learned value on PlaNet's frozen Boxing model: its rounds, over seeds"),
    "10_planet_value_planner": ("beyond", "CEM with that value at the end of its horizon; its levers on validation bouts"),
    "11_planning_budget": ("beyond (ch. 1)", "score against search budget: Sokoban's search, MCTS and CEM on Boxing, each "
                                             "without search and under growing budgets"),
}


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


def notebook_rows(folder: Path = CHECKOUT / "notebooks") -> list[dict]:
    """A row per notebook in ``folder`` (sorted): ``name``, ``section``, ``shows`` and ``stamp``.
    A notebook without an entry in :data:`SHOWS` raises ValueError naming it."""
    rows = []
    for path in sorted(Path(folder).glob("*.ipynb")):
        if path.stem not in SHOWS:
            raise ValueError(f"{path.name}: not in wmthesis.notebook_index.SHOWS; say what it shows there")
        section, shows = SHOWS[path.stem]
        rows.append({"name": path.stem, "section": section, "shows": shows, "stamp": notebook_stamp(path)})
    return rows


def _committed_run(stamp: dict | None) -> str:
    if stamp is None:
        return "awaiting a re-run on today's code"
    how = {"trained here": ", trained here", "from shipped runs": " from the shipped runs (from scratch: the results "
                                                                  "table's minutes a seed)"}.get(stamp["how"], "")
    return f"{max(1, round(stamp['seconds'] / 60))} min{how}, {stamp['profile']}, {stamp['date']}"


def notebook_table(rows: list[dict]) -> str:
    """The index as markdown."""
    lines = ["| notebook | thesis | what it shows | its committed run (2-core CPU) |", "|---|---|---|---|"]
    lines += [f"| `{r['name']}` | {r['section']} | {r['shows']} | {_committed_run(r['stamp'])} |" for r in rows]
    return "\n".join(lines)


__all__ = ["BEGIN", "END", "SHOWS", "notebook_stamp", "notebook_rows", "notebook_table"]
