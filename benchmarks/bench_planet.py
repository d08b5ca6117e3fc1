"""PlaNet: CEM planning time per action and RSSM training updates per second.

    python benchmarks/bench_planet.py [--repeats 5] [--updates 2] [--threads N] [--seed 0] [--out PATH]

Rows (a randomly initialised RSSM of the thesis sizes, 18 actions as in Boxing):

- ``bare forward``: the same RSSM advanced over I x H x J = 10 x 12 x 1000 = 120,000 latent
  steps in I batched passes of (J, H) random one-hot actions (transition, prior sample, reward):
  the floor any CEM at these sizes must pay.
- ``cem_plan``: one plan at the thesis sizes (H 12, J 1000, K 100, I 10); ``ratio`` is its time
  over the bare forward pass (target <= 1.2).
- ``agent step``: :class:`~wmthesis.planet.agent.PlanetMind` ``plan``: encode one frame,
  update the belief, then the CEM; and beside it the latent value agent's step
  (:class:`~wmthesis.value.latent_value.ValueMind`: encode, update, one transition per action and the
  value head; beyond the thesis), with its speed-up over the CEM step, and the same with the
  mean of 3 rounds' values (``agent_rounds`` 3: three times the heads), over the one value; and the CEM whose
  candidates end in that value (:class:`~wmthesis.value.planner.ValuePlanetMind`: the
  same J, K and I, the horizon of the profile's ``ValuePlannerConfig``), with its time over the
  plain CEM step (``vs_cem``), its first step seeded by the value as evaluated (one more value
  call per step); the same from the thesis's zero mean, without that call; and with every
  imagined step scored by the value (``rewards="value"``: H value calls per candidate). And the step of
  the collecting planner with Plan2Explore's bonus (:mod:`~wmthesis.planet.explore`: 5 one-step
  heads per imagined step; beyond the thesis), over the plain CEM step.
- The same two at the ``quick`` profile's planner sizes.
- ``update``: one training step through :func:`~wmthesis.training.gradient_step` (loss, NaN
  guard, backward, clipping, Adam) on 50 chunks of 50 steps of 64x64 frames, with latent
  overshooting (distance 50, the thesis default) and without (the best Boxing run); and at
  the ``quick`` profile's Atari sizes (12x24 chunks of 32x32 frames, networks of depth 16). Each beside a bare torch loop of the same model, loss and
  batch (``vs_bare``: the bare loop's seconds over ours; target >= 0.9), with updates per
  CPU-hour.

Times are medians over ``--repeats`` (``--updates`` for the training rows) after one warm-up;
the bare pass, the CEM and the agent step take turns, so their ratios survive a changing load.
On a shared machine, ``--threads 1`` avoids the OpenMP slowdown of two threads on busy cores.
Writes ``benchmarks/results/planet.json``; ``planet_cuda.json`` is the same script on one
NVIDIA H100 (``--repeats 5 --updates 3``, torch 2.11, CUDA picked up by itself).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.planet.config import PlaNetConfig

from wmthesis.value.config import LatentValueConfig, ValuePlannerConfig
from wmthesis.config import for_profile  # noqa: E402
from wmthesis.planet.profiles import planet_config  # noqa: E402
from wmthesis.planet.cem import cem_plan  # noqa: E402
from wmthesis.planet.explore import build_disagreement  # noqa: E402
from wmthesis.planet.rssm import planet_loss  # noqa: E402
from wmthesis.planet.agent import PlanetMind
from wmthesis.planet.train import batch_loss, build_model, make_optimizer  # noqa: E402
from wmthesis.value.latent_value import LatentValue, ValueMind, round_ensemble  # noqa: E402
from wmthesis.value.planner import ValuePlanetMind  # noqa: E402
from wmthesis.training import gradient_step  # noqa: E402
from _results import machine_meta, print_table, write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "planet.json"
N_ACTIONS = 18


def median_seconds(fns: dict, repeats: int) -> dict[str, float]:
    """Median wall time of each ``fns[name]()`` over `repeats` rounds after one warm-up.

    The functions take turns within each round, so that a machine whose load changes during
    the benchmark slows them alike and their ratios stay fair. CUDA is synchronised.
    """
    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
    times: dict[str, list[float]] = {name: [] for name in fns}
    for round_ in range(repeats + 1):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            sync()
            if round_:
                times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def planning_rows(model, cfg: PlaNetConfig, label: str, repeats: int, seed: int) -> list[dict]:
    """Bare forward pass, cem_plan and a PlanetMind step at the planner sizes of `cfg`."""
    dev = next(model.parameters()).device
    g = torch.Generator(dev).manual_seed(seed)
    belief = torch.randn(1, cfg.belief_size, generator=g, device=dev)
    state = torch.randn(1, cfg.state_size, generator=g, device=dev)
    sizes = (cfg.horizon, cfg.candidates, cfg.top_k, cfg.iterations)
    shape = (cfg.iterations, cfg.candidates, cfg.horizon)
    actions = F.one_hot(torch.randint(0, N_ACTIONS, shape, generator=g, device=dev), N_ACTIONS).float()
    rollout = lambda a: model.imagined_returns(belief, state, a, g)  # noqa: E731

    def bare():
        for batch in actions:
            rollout(batch)

    mind = PlanetMind.from_config(model, cfg, seed)
    explorer = build_disagreement(model, cfg.hidden_size, cfg.explore_heads)
    exploring = PlanetMind(model, horizon=cfg.horizon, candidates=cfg.candidates, top_k=cfg.top_k,
                           iterations=cfg.iterations, bits=cfg.bits, generator=torch.Generator(dev).manual_seed(seed),
                           explorer=explorer, explore_scale=10.0)
    value_cfg = LatentValueConfig()
    value = LatentValue(cfg.belief_size + cfg.state_size, value_cfg.hidden_size, value_cfg.heads).to(dev)
    value_mind = ValueMind(model, value, cfg.bits, seed)
    mean_mind = ValueMind(model, round_ensemble([value.state_dict()] * 3, value_cfg.hidden_size), cfg.bits, seed)
    planner = for_profile(ValuePlannerConfig, label)
    horizon = planner.horizon
    def value_cem(**changes) -> ValuePlanetMind:
        options = {**dict(imagine=planner.imagine, value_prior=planner.value_prior, rewards=planner.rewards), **changes}
        return ValuePlanetMind(model, value, horizon=horizon, candidates=cfg.candidates, top_k=cfg.top_k,
                               iterations=cfg.iterations, bits=cfg.bits, generator=torch.Generator(dev).manual_seed(seed),
                               **options)

    value_planner, zero_mean, value_rewards = value_cem(), value_cem(value_prior=0.0), value_cem(rewards="value")
    size = cfg.frame_size
    frame = np.random.default_rng(seed).integers(0, 32, (size, size, 3), dtype=np.uint8) * 8
    with torch.inference_mode():
        seconds = median_seconds({"bare": bare, "cem": lambda: cem_plan(rollout, N_ACTIONS, *sizes, g),
                                  "step": lambda: mind.plan(frame), "value": lambda: value_mind.plan(frame),
                                  "value_mean": lambda: mean_mind.plan(frame),
                                  "explore": lambda: exploring.plan(frame),
                                  "value_cem": lambda: value_planner.plan(frame),
                                  "value_cem_zero_mean": lambda: zero_mean.plan(frame),
                                  "value_cem_rewards": lambda: value_rewards.plan(frame)}, repeats)
    bare_s, cem_s, step_s, value_s = seconds["bare"], seconds["cem"], seconds["step"], seconds["value"]
    steps = cfg.iterations * cfg.horizon * cfg.candidates
    name = f"H{cfg.horizon} J{cfg.candidates} K{cfg.top_k} I{cfg.iterations}"
    return [dict(what=f"bare forward, {steps:,} latent steps ({label})", sizes=name, seconds=bare_s,
                 latent_steps_per_s=steps / bare_s),
            dict(what=f"cem_plan ({label})", sizes=name, seconds=cem_s, ratio=cem_s / bare_s),
            dict(what=f"agent step: encode + CEM ({label})", sizes=name, seconds=step_s, ratio=step_s / bare_s),
            dict(what=f"agent step while collecting: CEM + disagreement bonus ({label})", sizes=name,
                 seconds=seconds["explore"], vs_cem=seconds["explore"] / step_s),
            dict(what=f"agent step: encode + latent value ({label})", sizes=f"{N_ACTIONS} actions", seconds=value_s,
                 speedup_vs_cem=step_s / value_s),
            dict(what=f"agent step: encode + the mean of 3 rounds' values ({label})",
                 sizes=f"{N_ACTIONS} actions, {3 * value_cfg.heads} heads", seconds=seconds["value_mean"],
                 vs_value=seconds["value_mean"] / value_s),
            dict(what=f"agent step: encode + CEM with terminal value, seeded by it ({label})",
                 sizes=f"H{horizon} J{cfg.candidates} K{cfg.top_k} I{cfg.iterations}",
                 seconds=seconds["value_cem"], vs_cem=seconds["value_cem"] / step_s),
            dict(what=f"agent step: CEM with terminal value, from the zero mean ({label})",
                 sizes=f"H{horizon} J{cfg.candidates} K{cfg.top_k} I{cfg.iterations}",
                 seconds=seconds["value_cem_zero_mean"], vs_cem=seconds["value_cem_zero_mean"] / step_s),
            dict(what=f"agent step: CEM, every imagined step scored by the value ({label})",
                 sizes=f"H{horizon} J{cfg.candidates} K{cfg.top_k} I{cfg.iterations}",
                 seconds=seconds["value_cem_rewards"], vs_cem=seconds["value_cem_rewards"] / step_s)]


def update_row(cfg: PlaNetConfig, label: str, updates: int, seed: int) -> dict:
    """Seconds per training update at the config's batch."""
    torch.manual_seed(seed)
    model = build_model(cfg, N_ACTIONS)
    optimizer = make_optimizer(model, cfg)
    dev = next(model.parameters()).device
    g = torch.Generator(dev).manual_seed(seed)
    shape = (cfg.batch_size, cfg.chunk_length)
    size = cfg.frame_size
    observations = torch.randint(0, 32, (*shape, size, size, 3), generator=g, device=dev, dtype=torch.uint8) * 8
    actions = torch.randint(0, N_ACTIONS, shape, generator=g, device=dev)
    rewards = torch.randn(shape, generator=g, device=dev)

    batch = dict(observations=observations, actions=actions, rewards=rewards)

    def update():  # ours: the config's loss through the package's one guarded step
        gradient_step("PlaNet RSSM", 1, batch_loss(model, batch, cfg, g), optimizer, model.parameters(),
                      clip_norm=cfg.grad_clip)

    def bare():  # a bare torch loop of the same model, loss and batch
        loss = planet_loss(model, observations, actions, rewards, bits=cfg.bits, kl_scale=cfg.kl_scale,
                           free_nats=cfg.free_nats, decoder_variance=cfg.decoder_variance,
                           reward_scale=cfg.reward_scale, overshooting_distance=cfg.overshooting_distance,
                           overshooting_scale=cfg.overshooting_scale, generator=g)["loss"]
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        optimizer.step()

    seconds = median_seconds({"update": update, "bare": bare}, updates)
    sizes = (f"batch {shape[0]}x{shape[1]}, {cfg.frame_size}x{cfg.frame_size} depth {cfg.depth}, "
             f"overshooting {cfg.overshooting_distance}")
    frames = shape[0] * shape[1]
    return dict(what=f"update ({label})", sizes=sizes, seconds=seconds["update"], updates_per_s=1 / seconds["update"],
                updates_per_hour=3600 / seconds["update"], frames_per_s=frames / seconds["update"],
                bare_frames_per_s=frames / seconds["bare"], vs_bare=seconds["bare"] / seconds["update"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--updates", type=int, default=2)
    parser.add_argument("--threads", type=int, help="torch threads (default: torch's own choice)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    load_before = os.getloadavg()[0]
    thesis, quick = PlaNetConfig(), planet_config("boxing", "quick")
    torch.manual_seed(args.seed)
    model = build_model(thesis, N_ACTIONS).eval()
    results = planning_rows(model, thesis, "thesis", args.repeats, args.seed)
    results += planning_rows(build_model(quick, N_ACTIONS).eval(), quick, "quick", args.repeats, args.seed)
    results.append(update_row(thesis, "thesis", args.updates, args.seed))
    results.append(update_row(PlaNetConfig(overshooting_distance=0), "thesis, no overshooting",
                              args.updates, args.seed))
    results.append(update_row(quick, "quick", args.updates, args.seed))

    print_table(results, ["what", "sizes", "seconds", "ratio", "updates_per_s", "updates_per_hour", "frames_per_s",
                          "vs_bare", "latent_steps_per_s", "speedup_vs_cem", "vs_value", "vs_cem"])
    meta = machine_meta(seed=args.seed, repeats=args.repeats, updates=args.updates, threads=torch.get_num_threads(),
                        device=str(next(model.parameters()).device), cpus=os.cpu_count(),
                        gpu=torch.cuda.get_device_name() if torch.cuda.is_available() else None,
                        load_average_before=load_before, load_average_after=os.getloadavg()[0])
    write_results(args.out, meta, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
