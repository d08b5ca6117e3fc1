"""A trained World Models + AlphaZero agent as :func:`wmthesis.load` gives it (thesis 4.3): the
vision (boxing-wm's, with its decoder where one ships), the deterministic memory the search runs
in, and the search (the MCTS mind with the run's own settings and heads), on Boxing as it was scored.

    agent = wmthesis.load("boxing-wm-alphazero")       # own-memory, the default
    agent.search.config.simulations                     # the budget it was scored at
    agent.play(bouts=1)                                 # its first evaluation game
"""
from __future__ import annotations

from pathlib import Path

from wmthesis.agents import TrainedAgent
from wmthesis.alphazero.agent import load_agent
from wmthesis.world_models.trained import shipped_decoder


class AlphaZeroAgent(TrainedAgent):
    """boxing-wm-alphazero's agent: ``vision``, ``memory`` (the deterministic memory, with the
    run's reward model where it learned one: ``mdp``), ``search`` (an
    :class:`~wmthesis.alphazero.selfplay.AlphaZeroMind` as it searched in its evaluation games)
    and ``heads`` (policy and value on ``[z h]``)."""

    def __init__(self, path: Path, experiment: str, variant: str | None, profile: str, seed: int):
        loaded = load_agent(path)
        super().__init__(path, experiment, variant, profile, seed, loaded.info)
        self.loaded, self.config = loaded, loaded.config
        self.game, self.says_variant = "boxing", loaded.info["variant"]  # its format is Boxing's
        self.vision, self.heads = loaded.vision, loaded.heads
        self.memory = loaded.mdp  # the memory as the MDP the search runs in
        self.search = loaded.mind()
        self.decoder_info = shipped_decoder(self.vision, Path(path).parent)

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

    def score_line(self, plays: list[dict]) -> str:
        return super().score_line(plays)[:-1] + f", {self.config.simulations} simulations an action)"


def load_trained(path: Path, *, experiment: str, variant: str | None, profile: str, seed: int) -> AlphaZeroAgent:
    return AlphaZeroAgent(path, experiment, variant, profile, seed)


__all__ = ["AlphaZeroAgent", "load_trained"]
