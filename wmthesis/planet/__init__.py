"""PlaNet for discrete actions (thesis 3.2, 4.4): RSSM, discrete CEM, training, study, tuning.

Read in this order: ``rssm`` (the model and its loss), ``networks`` (its convolutional encoder
and decoder: World Models' VAE networks at the thesis's 64x64, thesis 4.4.1, and the same shape
for other frame sizes), ``cem`` (the planner), ``train`` (the agent, data collection and the
training loop), ``prediction`` (open-loop rollouts, scored on every pixel or on the moving
pixels against two baselines), ``study`` (the model study of 5.6.1-5.6.4), ``figures``,
``tuning`` (the random search over KL scale x free nats with optuna), and beyond the thesis
``explore`` (Plan2Explore's ensemble disagreement as a bonus while collecting: Freeway, where
random play never crosses). A learned value at the end of CEM's horizon is a wing of its own,
built on this one: :mod:`wmthesis.value`.
"""
