"""Value runs on PlaNet's Boxing model as tables (notebooks 09 and 10): the value agent beside the
baselines, the planners over seeds with their intervals, and levers or agent rules on the same
validation bouts, paired against the first."""
from __future__ import annotations

from wmthesis.metrics import aggregate, paired_difference, score_cell
from wmthesis.references import HUMAN, human


def agent_rows(results: dict[str, dict]) -> list[list[str]]:
    """The value agent's rules' results (``validate_agents``) as :func:`paired_rows`, each rule's
    rounds in place of a planner's changes, paired against the first rule."""
    def rounds(r: list[int]) -> str:
        return f"round {r[0]}" if len(r) == 1 else f"rounds {r[0]}-{r[-1]}"

    return paired_rows(results, {rule: rounds(scores["rounds"]) for rule, scores in results.items()})


def planner_lever_rows(results: dict[str, dict], levers: dict[str, dict]) -> list[list[str]]:
    """Planner levers' results (lever -> scores on the same validation bouts) as :func:`paired_rows`,
    each lever's changes to the planner (``levers``: lever -> changes) written out."""
    return paired_rows(results, {lever: ", ".join(f"{k}={v}" for k, v in levers.get(lever, {}).items()) or "(the default)"
                                 for lever in results})


def paired_rows(results: dict[str, dict], changes: dict[str, str]) -> list[list[str]]:
    """Results on the same bouts (name -> ``returns``, ``full`` and ``first``-500-step scores) as
    table rows: name, what it changes (``changes``), full-bout mean ± std, first-500-step mean, and
    the difference from the first's full-bout scores with its standard error (paired,
    :func:`~wmthesis.metrics.paired_difference`)."""
    first = next(iter(results.values()))
    rows = []
    for lever, scores in results.items():
        diff = paired_difference(scores["returns"], first["returns"])
        rows.append([lever, changes[lever], f"{scores['full']['mean']:.1f} ± {scores['full']['std']:.1f}",
                     f"{scores['first']['mean']:.1f}", f"{diff['difference']:+.1f} ± {diff['standard_error']:.1f}"])
    return rows


def planner_rows(by_seed: dict[int, dict], beside: dict[str, dict[int, dict]] | None = None) -> list[list[str]]:
    """The planners over seeds (``by_seed``: seed -> a value run's metrics, :func:`~wmthesis.value.comparison.fit_and_compare`), one
    row each: every seed's mean over its bouts, then the mean over seeds with its 95% t-interval
    (:func:`~wmthesis.metrics.aggregate`). ``beside``: label -> the same seeds' runs of
    another variant, whose CEM with the value is added as rows named with the label."""

    def planner(part, runs):
        return lambda seed: runs[seed]["value_planner"][part]["mean"]

    players = {"random play": lambda seed: by_seed[seed]["random"]["mean"],
               "PlaNet's CEM (thesis), full bouts": lambda seed: by_seed[seed]["planet"]["mean"],
               "value alone, full bouts": lambda seed: by_seed[seed]["value"]["mean"],
               "value alone, first 500 steps": lambda seed: by_seed[seed].get("value_first", {}).get("mean"),  # since 2026-11-24
               "CEM with the value, full bouts": planner("full", by_seed),
               "CEM with the value, first 500 steps": planner("first", by_seed)}
    for label, runs in (beside or {}).items():
        if set(runs) != set(by_seed):
            raise ValueError(f"{label!r} has seeds {sorted(runs)}, not the seeds {sorted(by_seed)}")
        players |= {f"CEM with the value ({label}), full bouts": planner("full", runs),
                    f"CEM with the value ({label}), first 500 steps": planner("first", runs)}
    rows = []
    for name, score in players.items():
        scores = [score(seed) for seed in by_seed]
        if None in scores:  # not measured in an older run
            continue
        summary = aggregate(scores)
        interval = "" if summary["ci_low"] is None else f" [{summary['ci_low']:.1f}, {summary['ci_high']:.1f}]"
        rows.append([name, *(f"{x:.1f}" for x in scores), f"{summary['mean']:.1f}{interval}"])
    return rows


def value_table(metrics: dict) -> str:
    """The value agent's chosen round beside random play and the CEM planner on the same bouts (markdown)."""
    diff, rounds = metrics["difference"], metrics.get("agent_rounds", [metrics["best_round"]])
    chosen = metrics["curve"][rounds[-1]]
    agent = (f"round {chosen['round']}, {chosen['episodes']} bouts of its own; chosen on {len(chosen['validation'])} "
             f"validation bouts" if len(rounds) == 1 else
             f"the mean of the values of rounds {rounds[0]}-{rounds[-1]}, up to {chosen['episodes']} bouts of its own")
    return "\n".join([
        "| player | full bout |", "|---|---|",
        f"| latent value on the PlaNet model ({agent}) | {score_cell(metrics['value'])} |",
        f"| PlaNet (CEM planner), same model | {score_cell(metrics['planet'])} |",
        *([f"| CEM with the value at the end of its {metrics['value_planner']['config']['horizon']} steps, same model "
           f"| {score_cell(metrics['value_planner']['full'])} |"] if "value_planner" in metrics else []),
        f"| random play, same bouts | {score_cell(metrics['random'])} |",
        f"| value - random | {diff['difference']:.1f} ± {diff['standard_error']:.1f} (s.e.) |",
        f"| human ({HUMAN['boxing'].source}) | {human('boxing')} |"])


def frozen_model_line(value_run: dict, agent_run: dict) -> str:
    """Which PlaNet model a value run froze, told by the thesis CEM's bouts on it against those of
    notebook 05's agent run of the same seed (the same 10 evaluation bouts): the same model, or an
    earlier training of that seed (a value fitted before the agent was trained again)."""
    ours, theirs = value_run["planet"], agent_run["agent"]["full"]
    same = all(abs(ours[k] - theirs[k]) < 1e-9 for k in ("mean", "std", "min", "max"))
    said = (f"the thesis's CEM scores {ours['mean']:.1f} on this value run's frozen PlaNet model and "
            f"{theirs['mean']:.1f} on notebook 05's agent of the same seed, over the same bouts: ")
    if same:
        return said + "the same model"
    return said + ("another training of that seed, from before the agent was trained again (the value run's "
                   "commit is older than the agent run's): each number is its own model's")


def other_episodes_line(value_run: dict, planet_run: dict, name: str) -> str:
    """The thesis CEM's score on a value run's evaluation episodes beside its PlaNet run's own test
    score (``planet_run``'s ``score``, of variant ``name``): one model, other episodes."""
    ours, theirs = value_run["planet"], planet_run["score"]
    return (f"PlaNet's CEM on {name}'s model scores {ours['mean']:.1f} over the value runs' {ours['episodes']} "
            f"evaluation episodes and {theirs['mean']:.1f} over its own run's {theirs['episodes']} test episodes "
            "above: other episodes")


__all__ = ["frozen_model_line", "other_episodes_line", "agent_rows", "planner_lever_rows", "paired_rows", "planner_rows", "value_table"]
