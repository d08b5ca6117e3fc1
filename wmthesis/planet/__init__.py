"""PlaNet for discrete actions (thesis 3.2, 4.4): RSSM, discrete CEM, training, tuning.

Read in this order: ``rssm`` (the model and its loss), ``cem`` (the planner), ``train`` (the
agent, data collection and the training loop), ``prediction`` (open-loop rollouts),
``figures``, ``tuning`` (the random search over KL scale x free nats with optuna). The
encoder and decoder are World Models' VAE networks (thesis 4.4.1), imported from that wing.
"""
