"""wmthesis: planning with learned world models (World Models, AlphaZero, PlaNet).

The reproducible companion to the thesis: one concept per module, named in its vocabulary.
"""
from wmthesis.utils import device, seed_everything

__version__ = "0.1.0"
__all__ = ["device", "seed_everything", "__version__"]
