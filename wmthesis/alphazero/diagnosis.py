"""Why World Models + AlphaZero does not learn (thesis 5.4.2 asks "why"), with figures.

- :func:`reward_error_by_depth`: the memory's reward (and latent) error k steps into the
  search, along real action sequences;
- :func:`value_predictability`: whether a linear value on ``[z h]`` predicts returns at all;
- :func:`action_predictability`: whether ``[z h]`` says which action earns more over the next
  steps (what any planner needs);
- :func:`search_statistics`: the value scale (search values against the returns that
  followed), the spread of the root Q against the prior bonus, ties and visit entropy;
- figures: :func:`plot_self_play`, :func:`plot_search`, :func:`plot_reward_error`,
  :func:`plot_visits`.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.alphazero.heads import value_targets
from wmthesis.alphazero.latent_mdp import LatentMDP, rollout_episodes, split_episodes, stack_rows
from wmthesis.alphazero.replay import Game
from wmthesis.metrics import correlation
from wmthesis.training import gradient_step

# ----------------------------------------------------------------------------- diagnosis
def reward_error_by_depth(mdp: LatentMDP, games, depth: int) -> dict:
    """How wrong the memory's rewards are k = 1..``depth`` steps into a search.

    For every step t of each game, the memory is warmed on the real latents and actions up to
    t, then rolled out from the real ``z_t`` along the *real* actions ``a_t..a_{t+k-1}`` on its
    own predicted latents; its k-th reward is compared with the true ``r_{t+k-1}``. Returns
    per depth (D,): ``reward_mse``, ``zero_mse`` (the error of always predicting 0: the rewards'
    second moment), ``hit_mse`` (the error on steps whose true reward is not 0) and
    ``latent_mse`` (squared error summed over L, against the encoded real latents), and the
    number of ``starts``.
    """
    L = mdp.latent_size
    sums = {key: np.zeros(depth) for key in ("reward", "zero", "hit", "latent")}
    counts = {key: np.zeros(depth) for key in ("reward", "hit", "latent")}
    for game in games:
        T = len(game)
        if T < depth:
            continue
        z_real = game.features[:, :L]
        h = np.zeros((T, mdp.hidden_size), np.float32)
        c = np.zeros_like(h)
        for t in range(T - 1):  # the warm state before each step t
            _, h[t + 1], c[t + 1], _, _ = mdp.step(z_real[t], h[t], c[t], int(game.actions[t]))
        t0 = np.arange(T - depth + 1)  # starts with depth real steps ahead
        z, hb, cb = z_real[t0], h[t0], c[t0]
        for k in range(depth):
            z, hb, cb, reward, _ = mdp.step(z, hb, cb, game.actions[t0 + k])
            truth = game.rewards[t0 + k]
            hit = truth != 0
            sums["reward"][k] += ((reward - truth) ** 2).sum()
            sums["zero"][k] += (truth ** 2).sum()
            sums["hit"][k] += ((reward - truth)[hit] ** 2).sum()
            valid = t0 + k + 1 < T  # the real latent that z predicts exists
            sums["latent"][k] += ((z[valid] - z_real[t0[valid] + k + 1]) ** 2).sum()
            counts["reward"][k] += len(t0)
            counts["hit"][k] += hit.sum()
            counts["latent"][k] += valid.sum()
    if not counts["reward"].any():
        raise ValueError(f"no game has {depth} steps")
    mean = lambda key, count: (sums[key] / np.maximum(counts[count], 1)).tolist()  # noqa: E731
    return {"depth": list(range(1, depth + 1)), "starts": int(counts["reward"][0]),
            "reward_mse": mean("reward", "reward"), "zero_mse": mean("zero", "reward"),
            "hit_mse": mean("hit", "hit"), "latent_mse": mean("latent", "latent")}


def value_predictability(mdp: LatentMDP, latents, gamma: float, n_step: int, val_fraction: float = 0.1,
                         ridge: float = 1.0) -> dict:
    """Can a linear value on ``[z h]`` predict returns at all? Fits one by ridge regression to
    the random rollouts (``latents``: a :class:`~wmthesis.world_models.train.LatentStore`;
    h from the memory reading each episode) and reports the correlation of its predictions with
    the targets on the training episodes and on the last ``val_fraction`` of episodes, for the
    ``monte-carlo`` returns and the ``n-step`` discounted reward sums (the bootstrap term
    needs a value, so here it is 0). ``reward``: the same for the memory's own reward head (the
    reward of each step against its prediction after reading the action)."""
    mu, actions, rewards = (latents.data[k].numpy() for k in ("mu", "actions", "rewards"))
    features, predicted = np.zeros((len(mu), mdp.latent_size + mdp.hidden_size)), np.zeros(len(mu))
    targets = {"monte-carlo": [], "n-step": []}
    for start, end in zip(latents.starts, latents.ends):
        h = np.zeros(mdp.hidden_size, np.float32)
        c = np.zeros_like(h)
        for t in range(start, end):
            features[t, :mdp.latent_size], features[t, mdp.latent_size:] = mu[t], h
            _, h, c, predicted[t], _ = mdp.step(mu[t], h, c, int(actions[t]))
        targets["monte-carlo"].append(value_targets(rewards[start:end], gamma))
        targets["n-step"].append(value_targets(rewards[start:end], gamma, n_step, np.zeros(end - start)))
    n_val = max(1, int(round(len(latents) * val_fraction))) if len(latents) > 1 else 0
    split = int(latents.starts[len(latents) - n_val]) if n_val else len(mu)
    train, val = slice(0, split), slice(split if n_val else 0, len(mu))
    x = np.hstack([features, np.ones((len(mu), 1))])
    result = {}
    for name, parts in targets.items():
        y = np.concatenate(parts)
        w = np.linalg.solve(x[train].T @ x[train] + ridge * np.eye(x.shape[1]), x[train].T @ y[train])
        result[name] = {"train_corr": correlation(x[train] @ w, y[train]), "val_corr": correlation(x[val] @ w, y[val])}
    result["reward"] = {"train_corr": correlation(predicted[train], rewards[train]),
                        "val_corr": correlation(predicted[val], rewards[val])}
    return result


def action_predictability(mdp: LatentMDP, latents, horizons=(3, 8), val_fraction: float = 0.15, epochs: int = 6,
                          hidden: int = 64, seed: int = 0) -> dict:
    """Does ``[z h]`` say *which action* is better? (What any planner on this model needs.)

    On the random rollouts (a :class:`~wmthesis.world_models.train.LatentStore`; h from the
    memory), fits an MLP ``Q(z, h, a)`` by MSE to the sum of the next k rewards
    ``r_t + ... + r_{t+k-1}`` (for each k in ``horizons``; the actions after a_t are random, so
    this is the random policy's Q) and reports on the last ``val_fraction`` of the episodes:
    ``q_corr`` (Q of the action taken against the sum), ``v_corr`` (its mean over the actions,
    V, against the sum) and ``advantage_corr``: ``Q(s, a_t) - V(s)`` against ``sum - V(s)``,
    the part of the outcome that the action explains. Near 0, no search in this model can choose
    better than at random. Also ``advantage_std``, the spread of Q over the actions.
    """
    episodes = rollout_episodes(mdp, latents)
    result = {}
    for k in horizons:
        windows = [(x[:len(x) - k + 1], a[:len(x) - k + 1], np.convolve(r, np.ones(k))[k - 1:len(x)].astype(np.float32))
                   for x, a, r in episodes if len(x) >= k]  # sums r_t + ... + r_{t+k-1}
        train, val = (stack_rows(part) for part in split_episodes(windows, val_fraction))
        result[str(k)] = _fit_q(train, val, mdp.n_actions, epochs, hidden, seed)
    return result


def _fit_q(train: tuple, val: tuple, n_actions: int, epochs: int, hidden: int, seed: int) -> dict:
    torch.manual_seed(seed)
    x, a, y = (torch.as_tensor(v) for v in train)
    mean, std = x.mean(0), x.std(0) + 1e-3
    net = nn.Sequential(nn.Linear(x.shape[1] + n_actions, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                        nn.Linear(hidden, 1))

    def q(features, actions):
        inputs = torch.cat([(features - mean) / std, F.one_hot(actions, n_actions).float()], -1)
        return net(inputs).squeeze(-1)

    optimiser = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-4)
    rng = np.random.default_rng(seed)
    update = 0
    for _ in range(epochs):
        for batch in torch.from_numpy(rng.permutation(len(y))).split(256):
            update += 1
            gradient_step("diagnosis Q probe", update, {"loss": F.mse_loss(q(x[batch], a[batch]), y[batch])},
                          optimiser, net.parameters())
    xv, av, yv = (torch.as_tensor(v) for v in val)  # Q of every action on the held-out rows
    with torch.no_grad():
        every = torch.stack([q(xv, torch.full_like(av, j)) for j in range(n_actions)], 1).numpy()
    taken, v, yv = every[np.arange(len(yv)), av.numpy()], every.mean(1), yv.numpy()
    return {"q_corr": correlation(taken, yv), "v_corr": correlation(v, yv),
            "advantage_corr": correlation(taken - v, yv - v),
            "advantage_std": float((every - v[:, None]).std()), "val_rows": int(len(yv))}


def search_statistics(games, gamma: float, c: float, simulations: int) -> dict:
    """Value scale and Q spread of the searches in ``games``.

    ``root_value``/``returns``: the searches' root values and the discounted returns that
    followed them (each (N,)); ``q_spread`` (N,): max - min of the root Q over visited actions;
    ``prior_bonus``: the PUCT bonus ``c * P * sqrt(N(s)) / (1 + N(s, a))`` of an action with a
    uniform prior visited once when the root has had all ``simulations`` (the scale that Q
    differences must beat to steer the search); ``visit_entropy`` (N,) of the root visit
    distributions; ``tied``: the fraction of steps whose highest visit count was shared by
    several actions; ``value_return_corr``: the correlation of root values and returns.
    """
    root_values = np.concatenate([g.root_values for g in games])
    returns = np.concatenate([value_targets(g.rewards, gamma) for g in games])
    q = np.concatenate([g.q for g in games])
    visited = np.isfinite(q)
    spread = np.where(visited.sum(-1) > 1, np.nanmax(np.where(visited, q, -np.inf), -1)
                      - np.nanmin(np.where(visited, q, np.inf), -1), 0.0)
    policies = np.concatenate([g.policies for g in games])
    entropy = -(policies * np.log(np.where(policies > 0, policies, 1))).sum(-1)
    A = q.shape[1]
    tied = float(np.mean((policies == policies.max(-1, keepdims=True)).sum(-1) > 1))
    return {"root_value": root_values, "returns": returns, "q_spread": spread, "visit_entropy": entropy, "tied": tied,
            "prior_bonus": c / A * math.sqrt(simulations) / 2, "value_return_corr": correlation(root_values, returns)}


# ----------------------------------------------------------------------------- figures
def plot_self_play(runs: dict, references: dict | None = None, ax=None):
    """Self-play return per game (thin; thick: moving mean over 10 games) and the greedy test
    scores (mean +- std) of each run in ``runs`` (name -> :meth:`AlphaZeroRun.summary`)."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6.5, 3.5))
    for index, (name, run) in enumerate(runs.items()):
        colour = f"C{index}"
        games = np.array([e["game"] for e in run["curve"]])
        returns = np.array([e["return"] for e in run["curve"]])
        ax.plot(games, returns, color=colour, lw=0.6, alpha=0.4)
        window = min(10, len(returns))
        if window > 1:
            smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
            ax.plot(games[window - 1:], smooth, color=colour, lw=1.8, label=f"{name}: self-play (mean of {window})")
        if run["tests"]:
            ax.errorbar([t["game"] for t in run["tests"]], [t["mean"] for t in run["tests"]],
                        [t["std"] for t in run["tests"]], fmt="o", ms=4, capsize=2, color=colour,
                        label=f"{name}: greedy test")
    for index, (name, value) in enumerate((references or {}).items()):
        ax.axhline(value, color="0.4", ls=["--", ":", "-."][index % 3], lw=1, label=name)
    ax.set_xlabel("self-play game")
    ax.set_ylabel("game score")
    ax.set_title("AlphaZero self-play in the memory's latent space")
    ax.legend(fontsize=7)
    ax.figure.tight_layout()
    return ax.figure


def plot_search(games_by_variant: dict, gamma: float, c: float, simulations: int):
    """Search statistics and diagnosis per variant (``games_by_variant``: name -> games): value
    scale, root value along the first game against the return that followed, Q spread against
    the prior bonus, visit entropy, the actions taken, the search depth."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 6.4))
    axes = axes.ravel()
    width = 0.8 / max(len(games_by_variant), 1)
    for index, (name, games) in enumerate(games_by_variant.items()):
        colour = f"C{index}"
        stats = search_statistics(games, gamma, c, simulations)
        axes[0].scatter(stats["returns"], stats["root_value"], s=3, alpha=0.3, color=colour,
                        label=f"{name} (r={stats['value_return_corr']:.2f})")
        axes[1].plot(games[0].root_values, color=colour, lw=1, label=f"{name}: root value")
        axes[1].plot(value_targets(games[0].rewards, gamma), color=colour, lw=1, ls="--",
                     label=f"{name}: return that followed")
        spread = np.maximum(stats["q_spread"], 1e-5)
        axes[2].hist(spread, bins=np.geomspace(1e-5, max(spread.max(), 1e-3) * 1.5, 30), alpha=0.5, color=colour,
                     label=name)
        axes[3].hist(stats["visit_entropy"], bins=30, alpha=0.5, color=colour,
                     label=f"{name} (top count tied: {stats['tied']:.0%})")
        actions = np.bincount(np.concatenate([g.actions for g in games]), minlength=games[0].q.shape[1])
        axes[4].bar(np.arange(len(actions)) + index * width, actions / actions.sum(), width, color=colour, label=name)
        depths = np.concatenate([g.depths for g in games])
        axes[5].hist(depths, bins=np.arange(depths.max() + 2) - 0.5, alpha=0.5, color=colour, label=name)
    lims = axes[0].get_xlim()
    axes[0].plot(lims, lims, color="0.5", lw=0.8)
    axes[0].set(xlabel="discounted return that followed", ylabel="root value", title="value scale")
    axes[1].set(xlabel="step of the first evaluation game", ylabel="value", title="root value vs return")
    axes[2].axvline(stats["prior_bonus"], color="k", ls="--", lw=1, label="prior bonus (uniform P)")
    axes[2].set(xscale="log", xlabel="max - min root Q (visited actions)", ylabel="steps", title="spread of root Q")
    axes[3].axvline(math.log(games[0].q.shape[1]), color="k", ls="--", lw=1, label="uniform")
    axes[3].set(xlabel="entropy of root visits (nats)", ylabel="steps", title="visit distributions")
    axes[4].set(xlabel="action (0 = no-op)", ylabel="fraction of steps", title="actions taken")
    axes[5].set(xlabel="longest path in the search (edges)", ylabel="steps", title="search depth")
    for ax in axes:
        ax.legend(fontsize=6)
    fig.tight_layout()
    return fig


def plot_reward_error(errors: dict, search_depths=None, ax=None):
    """The memory's reward error against the depth into the search (:func:`reward_error_by_depth`),
    beside the error of always predicting 0; ``search_depths``: the searches' max depths."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5, 3.2))
    d = errors["depth"]
    ax.plot(d, errors["reward_mse"], "o-", ms=3, label="memory's reward, all steps")
    ax.plot(d, errors["zero_mse"], "--", color="0.4", label="predicting 0, all steps")
    ax.plot(d, errors["hit_mse"], "s-", ms=3, label="memory's reward, steps with a hit")
    if search_depths is not None and len(search_depths):
        ax.axvline(float(np.median(search_depths)), color="k", ls=":", lw=1, label="median search depth")
    ax.set(xlabel="steps into the search (k)", ylabel="reward MSE", yscale="log",
           title="reward-model error along the search depth")
    ax.legend(fontsize=7)
    ax.figure.tight_layout()
    return ax.figure


def plot_visits(game: Game, steps: int = 60, ax=None):
    """The root visit distribution (actions x steps) over the first ``steps`` steps of a game,
    with the action taken marked."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 2.8))
    policies = game.policies[:steps].T
    image = ax.imshow(policies, aspect="auto", cmap="viridis", interpolation="nearest")
    ax.scatter(np.arange(policies.shape[1]), game.actions[:steps], s=4, color="r", label="action taken")
    ax.set(xlabel="step", ylabel="action", title="root visit distributions")
    ax.figure.colorbar(image, ax=ax, fraction=0.03)
    ax.legend(fontsize=7, loc="upper right")
    ax.figure.tight_layout()
    return ax.figure
