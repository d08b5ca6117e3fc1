"""wmthesis: planning with learned world models (World Models, AlphaZero, PlaNet).

The reproducible companion to the thesis: one concept per module, named in its vocabulary.
"""
import os

# Idle OpenMP threads of torch must not spin: they would take the cores from ale-py's
# stepping threads (measured: 2,300 -> 530 env steps/s). Only effective before torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from wmthesis.utils import device, seed_everything  # noqa: E402

__version__ = "0.1.0"
__all__ = ["device", "seed_everything", "__version__"]
