"""A learned value on PlaNet's frozen model (beyond the thesis, which plans with the model's
imagined rewards alone): a short-horizon action value fitted on the RSSM's features
(:mod:`~wmthesis.value.latent_value`), in rounds of its own play (:mod:`~wmthesis.value.rounds`),
CEM that ends in it (:mod:`~wmthesis.value.planner`), how far it reads the model's imagination
(:mod:`~wmthesis.value.signal`) and its agent file (:mod:`~wmthesis.value.agent_file`). It builds
on the PlaNet wing (:mod:`wmthesis.planet`) and nothing else of the package's wings."""
