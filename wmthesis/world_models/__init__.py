"""World Models (thesis 3.1, 4.2): vision (VAE), memory (MDN-RNN), controller (CMA-ES).

Read in this order: ``vision`` (the VAE and the vision a controller sees), ``memory`` (MDN-RNN,
deterministic and auxiliary variants), ``controller`` (the linear policy and its mind),
``train`` (vision and memory on an episode store), ``evolution`` (CMA-ES in the real game or
the dream), ``prediction`` (open-loop rollouts), ``grid`` (grid states as latents, 5.3.2),
``sokoban`` (the Sokoban measurements of 5.3), ``figures``.
"""
