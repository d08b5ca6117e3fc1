"""wmthesis: planning with learned world models (World Models, AlphaZero, PlaNet).

The reproducible companion to the thesis: one concept per module, named in its vocabulary.
"""
import os
import warnings

# tqdm.auto (imported by dependencies) warns in a notebook without ipywidgets; the bars fall back
# to text, which is all a reader needs.
warnings.filterwarnings("ignore", message="IProgress not found")

# Idle OpenMP threads of torch must not spin: they would take the cores from ale-py's
# stepping threads (measured: 2,300 -> 530 env steps/s). Only effective before torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
__all__ = ["load", "agent_file", "headlines", "device", "seed_everything", "__version__"]


def __getattr__(name: str):
    """``wmthesis.load`` and ``wmthesis.agent_file`` (:mod:`wmthesis.agents`), ``wmthesis.headlines``
    (:mod:`wmthesis.summary`), ``wmthesis.device`` and
    ``wmthesis.seed_everything`` (:mod:`wmthesis.utils`), loaded when first asked for: importing the
    package (the command line) does not load torch."""
    if name in ("load", "agent_file"):
        from wmthesis import agents

        return getattr(agents, name)
    if name == "headlines":
        from wmthesis.summary import headlines

        return headlines
    if name in ("device", "seed_everything"):
        from wmthesis import utils

        return getattr(utils, name)
    raise AttributeError(f"module 'wmthesis' has no attribute {name!r}")
