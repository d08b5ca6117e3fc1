"""Sokoban solved by search in a learned model (beyond the thesis: its aim, chapter 1, where 5.3
and 5.5 stopped at 0 solved levels).

Read in this order: ``model`` (the learned model over a grid of discrete cells), ``cells`` (the
cell codes: the grid's types, or learned from pixels), ``search`` (batched best-first search in
any model, and the true rules as one), ``heuristic`` (the learned steps-to-go value, and the labels it backs up from a search's graph), ``agent``
(plan, play, replan in the real game), ``experience`` and ``iteration`` (expert iteration:
random play, then rounds of the agent's own play), ``accuracy``, ``evaluation``, ``figures``.

Why best-first search and not the AlphaZero wing's MCTS: on 30 ``sokoban-small`` levels with the
true rules, uniform priors and no value, MCTS solved 4 with 100 simulations a move (10,433 model
calls a level) and 7 with 400 (37,240); breadth-first search with duplicate states merged
solved all 30 with 379 expanded nodes a level (3,032 model calls). Sokoban's reward is sparse
and its states recur along many paths, which MCTS's tree does not merge.
"""
