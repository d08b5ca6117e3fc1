"""A trained World Models + AlphaZero agent as :func:`wmthesis.load` gives it (thesis 4.3): the
vision (boxing-wm's, with its decoder where one ships), the deterministic memory the search runs
in, and the search (the MCTS mind with the run's own settings and heads), on Boxing as it was scored.

    agent = wmthesis.load("boxing-wm-alphazero")       # own-memory, the default
    agent.search.config.simulations                     # the budget it was scored at
    agent.play(bouts=1)                                 # its first evaluation game
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from wmthesis.agents import TrainedAgent
from wmthesis.alphazero.agent import load_agent
from wmthesis.world_models.trained import shipped_decoder


class AlphaZeroAgent(TrainedAgent):
    """boxing-wm-alphazero's agent: ``vision``, ``memory`` (the deterministic memory, with the
    run's reward model where it learned one: ``mdp``), ``search`` (an
    :class:`~wmthesis.alphazero.selfplay.AlphaZeroMind` as it searched in its evaluation games)
    and ``heads`` (policy and value on ``[z h]``)."""

    decoded = "the vision's reconstructions and the principal variation's frames"
    fit_decoder = "python tools/fit_decoders.py world-models"

    def __init__(self, path: Path, experiment: str, variant: str | None, profile: str, seed: int):
        loaded = load_agent(path)
        super().__init__(path, experiment, variant, profile, seed, loaded.info)
        self.loaded, self.config = loaded, loaded.config
        self.game, self.says_variant = "boxing", loaded.info["variant"]  # its format is Boxing's
        self.vision, self.heads = loaded.vision, loaded.heads
        self.memory = loaded.mdp  # the memory as the MDP the search runs in
        self.search = loaded.mind()
        self.decoder_info = shipped_decoder(self.vision, Path(path).parent)
        self.max_steps = self.config.eval_max_steps

    def env(self):
        """Boxing with World Models frames and no-op starts (:func:`~wmthesis.envs.atari.boxing_env`),
        as its games were played."""
        from wmthesis.envs.atari import boxing_env

        return boxing_env(self.config.noop_max)

    def mind(self, simulations: int | None = None, seed: int = 0):
        """The search as it played its evaluation games (``simulations``: another budget), its
        noise from ``seed``."""
        mind = self.loaded.mind(simulations)
        mind.new_search(seed, 0)
        return mind

    def scored_seeds(self, bouts: int) -> list[int]:
        from wmthesis.alphazero.evaluation import evaluation_seeds
        from wmthesis.alphazero.replay import game_seeds

        return [game_seeds(s)[0] for s in evaluation_seeds(self.seed, bouts, self.config.noop_max)]

    def play_bouts(self, bouts: int, frames: list | None = None, on_bout=None) -> list[dict]:
        from wmthesis.alphazero.evaluation import evaluation_seeds
        from wmthesis.alphazero.selfplay import play as play_game

        mind, env, plays = self.loaded.mind(), self.env(), []
        try:
            for k, game_seed in enumerate(evaluation_seeds(self.seed, bouts, self.config.noop_max)):
                mind.keep_frames = frames is not None
                game = play_game(env, mind, game_seed, k, train_mode=False, max_steps=self.config.eval_max_steps)
                plays.append({"bout": k, "return": float(game.score), "steps": len(game.actions)})
                if frames is not None and game.frames is not None:
                    frames.append(game.frames)
                if on_bout is not None:
                    on_bout(plays[-1])
        finally:
            env.close()
        return plays

    def scored_minds(self, bouts: int) -> list[tuple[int, object]]:
        from wmthesis.alphazero.evaluation import evaluation_seeds
        from wmthesis.alphazero.replay import game_seeds

        minds = []
        for k, game_seed in enumerate(evaluation_seeds(self.seed, bouts, self.config.noop_max)):
            env_seed, search_seed = game_seeds(game_seed)
            mind = self.loaded.mind()
            mind.new_search(search_seed, k)
            minds.append((env_seed, mind))
        return minds

    def thought(self, mind):
        """What the search weighed at its root (visits, Q, prior per action) and what it imagines:
        its principal variation (the most visited path, up to ``horizon`` steps) with the
        rewards the memory predicts along it, decoded; the vision's reconstruction of the frame."""
        from wmthesis.thoughts import Thought

        root = mind.mcts.root
        if root is None or root.terminal:
            return Thought()
        latents, rewards = principal_variation(root, self.horizon)
        thought = Thought(imagined_rewards=rewards, scores={"visits": root.N.copy(), "q": np.where(root.N > 0, root.Q, 0.0),
                                                            "prior": root.P.copy()},
                          values={"depth": float(len(latents)), "root_value": float(root.N @ root.Q / max(root.N.sum(), 1))})
        if self.decoder_info is not None:
            frames = self.vision.decode(np.stack([root.state.z, *latents]))
            thought.seen, thought.imagined = frames[0], {j + 1: f for j, f in enumerate(frames[1:])}
        return thought

    def dream(self, frames, actions, context: int = 60, horizon: int = 10) -> dict:
        """The search's memory warmed on ``context`` real steps of an episode (``frames`` (T, 64, 64, 3)
        uint8, ``actions`` (T,), ``actions[t]`` taken at ``frames[t]``), then stepping ``horizon``
        steps on its own predictions along the actions taken, as the search imagines: ``truth`` and
        ``prediction`` frames (horizon, 64, 64, 3), ``pixel_error`` and ``latent_error`` per step
        (World Models' :meth:`~wmthesis.world_models.trained.WorldModelsAgent.dream`, for this memory)."""
        from wmthesis.agents import check_episode
        from wmthesis.alphazero.latent_mdp import State
        from wmthesis.metrics import horizon_errors

        frames = np.asarray(frames)
        actions = check_episode(frames, actions, context + horizon, self.memory.n_actions)
        if context < 1:
            raise ValueError(f"a dream starts from at least one real step: context {context}")
        mind = self.filter(frames[:context], actions[:context - 1])
        state, predicted = State(mind.encode(frames[context - 1]), mind.h, mind.c), []
        for t in range(context - 1, context + horizon - 1):
            state, _ = mind.mdp.transition(state, int(actions[t]))
            predicted.append(np.asarray(state.z, np.float32))
        truth, predicted = frames[context:context + horizon], np.stack(predicted)
        prediction = np.asarray(self.vision.decode(predicted))
        seen = np.stack([mind.encode(frame) for frame in truth])
        return {"truth": truth, "prediction": prediction, "pixel_error": horizon_errors(truth, prediction),
                "latent_error": horizon_errors(seen, predicted)}

    def step_prediction(self, mind, frame, action: int) -> dict:
        """The search's model's step from the frame: the memory's next latent, decoded, and its reward."""
        from wmthesis.alphazero.latent_mdp import State

        following, reward = mind.mdp.transition(State(mind.encode(frame), mind.h, mind.c), action)
        shown = self.vision.decode(np.stack([following.z]))[0] if self.decoder_info is not None else None
        return {"frame": None if shown is None else np.asarray(shown), "reward": float(reward)}

    def score_line(self, plays: list[dict]) -> str:
        return super().score_line(plays)[:-1] + f", {self.config.simulations} simulations an action)"


def principal_variation(root, horizon: int) -> tuple[list[np.ndarray], np.ndarray]:
    """The search tree's most visited path from ``root`` (a :class:`~wmthesis.alphazero.mcts.Node`),
    ``horizon`` edges at most: its latents z (L,) each and the model's rewards on its edges."""
    latents, rewards, node = [], [], root
    while len(latents) < horizon and node is not None and not node.terminal and node.N.sum() > 0:
        action = int(node.N.argmax())
        child = node.children[action]
        if child is None:
            break
        latents.append(np.asarray(child.state.z, np.float32))
        rewards.append(float(node.R[action]))
        node = child
    return latents, np.asarray(rewards)


def load_trained(path: Path, *, experiment: str, variant: str | None, profile: str, seed: int) -> AlphaZeroAgent:
    return AlphaZeroAgent(path, experiment, variant, profile, seed)


__all__ = ["AlphaZeroAgent", "load_trained", "principal_variation"]
