"""World Models + AlphaZero (thesis 4.3): tree search in the deterministic memory.

Read in this order: ``mcts`` (the search over any MDP), ``latent_mdp`` (the memory as that MDP,
and a learned reward model), ``replay`` (played games, kept in HDF5), ``heads`` (policy and
value heads and their loss), ``selfplay`` (the mind and the training run), ``imitation``
(expert games, beyond the thesis), ``diagnosis`` (why self-play does not learn, and figures).
It builds on World Models' vision and memory, as the thesis does.
"""
