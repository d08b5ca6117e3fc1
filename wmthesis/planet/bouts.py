"""One bout (a full episode) of PlaNet on an Atari game, and bouts summed up: a bout's return,
the return of its first :data:`FIRST_STEPS` agent steps (the author's PlaNet runs capped episodes
at 2,000 frames, 500 agent steps: like is compared with like) and its length."""
from __future__ import annotations

from pathlib import Path

from wmthesis.core import ConstantMind, RandomMind, loop
from wmthesis.rollouts import EpisodeBuffer
from wmthesis.metrics import score_cell, score_summary
from wmthesis.references import HUMAN, THESIS_PLANET_BOXING, human
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.train import load_planet
from wmthesis.planet.variants import PLANET_BOXING
from wmthesis.planet.frames import make_planet_env
from wmthesis.planet.agent import play_greedy

FIRST_STEPS = 500  # 2,000 frames at action repeat 4: the author's episode cap


def play_bout(env_name: str, config: PlaNetConfig, run_dir: Path | None, env_seed: int, mind_seed: int,
              action: int | None = None) -> dict:
    """One full episode, greedy PlaNet from ``run_dir`` (when None: random play, or ``action``
    at every step where given): its ``return``, the return of its first :data:`FIRST_STEPS`
    steps, and its ``steps``."""
    env = make_planet_env(env_name, config)
    try:
        if run_dir is None:
            record, n = EpisodeBuffer(), env.action_space.n
            mind = RandomMind(n, seed=mind_seed) if action is None else ConstantMind(n, action)
            loop(env, mind, policy="deterministic", callbacks=[record], seed=env_seed, train_mode=False)
            rewards = [float(r) for r in record.episode["rewards"]]
        else:
            model, trained, _ = load_planet(run_dir)
            rewards = play_greedy(env, model, trained, env_seed, mind_seed)
    finally:
        env.close()
    return bout_result(rewards)


def bout_result(rewards) -> dict:
    """One bout's rewards (T,) summed: its ``return``, the return of its first
    :data:`FIRST_STEPS` steps and its ``steps``."""
    return {"return": float(sum(rewards)), "first": float(sum(rewards[:FIRST_STEPS])), "steps": len(rewards)}


def bout_scores(plays: list[dict]) -> dict:
    """:func:`play_bout`'s plays summed up: ``full`` and ``first``-500-step scores
    (:func:`~wmthesis.metrics.score_summary`) with their ``returns`` and ``first_returns``, and the
    ``ms_per_action`` where every play was timed."""
    timed = all("seconds" in p for p in plays)
    return {"full": score_summary([p["return"] for p in plays]), "first": score_summary([p["first"] for p in plays]),
            "returns": [p["return"] for p in plays], "first_returns": [p["first"] for p in plays],
            **({"ms_per_action": 1000 * sum(p["seconds"] for p in plays) / max(1, sum(p["steps"] for p in plays))}
               if timed else {})}


def agent_table(metrics: dict) -> str:
    """The agent's bouts beside random play on the same bouts and the references (markdown)."""
    diff, first = metrics["difference"], metrics["difference_first"]
    return "\n".join([
        "| player | full bout | first 500 agent steps |", "|---|---|---|",
        f"| PlaNet (KL scale 0.03, free nats 12), {metrics['env_steps']:,} agent steps, {metrics['updates']:,} updates "
        f"| {score_cell(metrics['agent']['full'])} | {score_cell(metrics['agent']['first'])} |",
        f"| random play, same bouts | {score_cell(metrics['random']['full'])} | {score_cell(metrics['random']['first'])} |",
        f"| agent - random | {diff['difference']:.1f} ± {diff['standard_error']:.1f} (s.e.) "
        f"| {first['difference']:.1f} ± {first['standard_error']:.1f} (s.e.) |",
        f"| human ({HUMAN['boxing'].source}) | {human('boxing')} | |",
        f"| thesis PlaNet ({THESIS_PLANET_BOXING.source}) | {THESIS_PLANET_BOXING.value} | |"])


def budget_table(config, metrics: dict, benchmark: dict | None = None) -> str:
    """Our PlaNet run's training budget beside the thesis's (Markdown): ``config``, the run's
    :class:`~wmthesis.planet.config.PlaNetConfig`, against the thesis's best Boxing setting (its
    defaults, 4.4.3-4.4.5, latent overshooting included, with the KL scale and free nats of
    5.6.3-5.6.4; what it does not state, "not stated") and PlaNet's public defaults
    (:data:`~wmthesis.references.PLANET_PUBLIC_DEFAULTS`); ``metrics``, the run's (agent steps and updates it
    spent); ``benchmark``, ``benchmarks/results/planet.json`` where given: what one update and one
    plan cost on the machine it measured, at both sizes."""
    import dataclasses

    from wmthesis.references import PLANET_PUBLIC, PLANET_PUBLIC_DEFAULTS

    tuned = PLANET_BOXING.changes(PLANET_BOXING.default.name)
    thesis = dataclasses.replace(type(config)(), kl_scale=tuned["kl_scale"], free_nats=tuned["free_nats"])
    measured = {r["what"]: r["seconds"] for r in (benchmark or {}).get("results", [])}

    def cost(name: str) -> str:
        return f"{measured[name]:.2f} s" if name in measured else "not measured"

    rows = [("frames", f"{config.frame_size}x{config.frame_size}, {config.bits} bits",
             f"{thesis.frame_size}x{thesis.frame_size}, {thesis.bits} bits"),
            ("encoder depth (first convolution's channels)", config.depth, thesis.depth),
            ("batch (chunks x steps)", f"{config.batch_size} x {config.chunk_length}",
             f"{thesis.batch_size} x {thesis.chunk_length}"),
            ("latent overshooting distance", config.overshooting_distance, thesis.overshooting_distance),
            ("random seed bouts", config.seed_episodes, thesis.seed_episodes),
            ("updates between collected bouts", f"{config.update_steps:,}", f"{thesis.update_steps:,}"),
            ("updates in all", f"{metrics['updates']:,}", "not stated"),
            ("agent steps collected", f"{metrics['env_steps']:,}", "not stated"),
            ("CEM: candidates x horizon x iterations", f"{config.candidates} x {config.horizon} x {config.iterations}",
             f"{thesis.candidates} x {thesis.horizon} x {thesis.iterations}")]
    if benchmark is not None:
        where = f"{benchmark['meta'].get('cores')} cores, {benchmark['meta'].get('threads')} thread(s)"
        rows += [(f"one update ({where})", cost("update (quick)"), cost("update (thesis)")),
                 (f"one plan ({where})", cost("cem_plan (quick)"), cost("cem_plan (thesis)"))]
    changed = [f.name for f in dataclasses.fields(config) if getattr(config, f.name) != getattr(thesis, f.name)]
    lines = ["| | ours | the thesis | PlaNet's public defaults |", "|---|---|---|---|"]
    lines += [f"| {name} | {ours} | {theirs} | {PLANET_PUBLIC_DEFAULTS.get(name, 'not measured')} |"
              for name, ours, theirs in rows]
    return ("\n".join(lines) + f"\n\nEvery setting of ours that differs from the thesis's best Boxing setting: "
            f"{', '.join(changed)}. PlaNet's public defaults: {PLANET_PUBLIC}.")


__all__ = ["budget_table", "agent_table", "FIRST_STEPS", "play_bout", "bout_result", "bout_scores"]
