"""What the thesis says about each of its figures that a notebook draws again (Fig. 54-511).

For each figure: its section, the thesis's own caption, and the sentences of that section that
make a claim about it, all quoted verbatim from the thesis's text (its figure numbers lost their
dot there: "Fig. 54" is Figure 5.4). :func:`thesis_says` gives them as a Markdown blockquote, which
a notebook shows right under its own figure, so a reader can hold the claim against the picture:

    display(Markdown(thesis_says("5.4")))
"""
from __future__ import annotations

from typing import NamedTuple


class ThesisFigure(NamedTuple):
    """One figure of the thesis: the ``section`` it is in, its ``caption`` (without the "Fig. 54."
    that opens it) and ``says``, the passages of that section about it, each verbatim."""

    section: str
    caption: str
    says: tuple[str, ...]


# Fig. 58 to 511 share most of their caption: PlaNet's open-loop rollouts after five true frames.
_ROLLOUT = ("Each row depicts the model rollout in one episode. The first five columns include original consecutive "
            "observations from the evaluation dataset from which the rollouts start. The model hidden state was "
            "initialized on these transitions. Each subsequent reconstruction was obtained by first predicting the "
            "next latent state by the model and then decoding it using the decoder.")
_VISION = ("First and third columns include original observations. Second and fourth columns include reconstructions. "
           "Each reconstruction was obtained by first encoding the original observation and then decoding it, using "
           "VAE encoder and decoder respectively.")
_MEMORY = ("Each row depicts the memory model rollout in one episode. The first column include original observations "
           "from the evaluation dataset from which the rollouts start. The RNN{apostrophe}s hidden state was "
           "initialized on preceding transitions in each episode. Each subsequent reconstruction was obtained by first "
           "predicting the next latent state by the memory model and then decoding it using the VAE decoder.")
_VISION_SAYS = ("The vision model successfully learned to encode high dimensional observations into low dimensional "
                "latent states.")

FIGURES: dict[str, ThesisFigure] = {
    "5.4": ThesisFigure("5.3.1", f"Qualitative result of the vision model training in Sokoban. {_VISION}", (
        _VISION_SAYS + " Fig. 54 shows original observations (first and third columns) side by side with "
        "reconstructed observations from their encodings (second and fourth columns).",)),
    "5.5": ThesisFigure("5.3.1", "Qualitative result of the memory model training in Sokoban. "
                        + _MEMORY.format(apostrophe="’"), (
        "The stochastic and deterministic memory models were not able to learn Sokoban's dynamics. Fig. 55 shows that "
        "the stochastic model very often can not determine the agents position. The agent disappears and blocks change "
        "their types. The eighth row shows that pushing mechanics are not modeled, the agent passes through boxes. The "
        "deterministic model does not do better.",)),
    "5.6": ThesisFigure("5.4.1", f"Qualitative result of the vision model training in Boxing. {_VISION}", (
        _VISION_SAYS + " Fig. 56 shows original observations (first and third columns) side by side with "
        "reconstructed observations from their encodings (second and fourth columns).",)),
    "5.7": ThesisFigure("5.4.1", "Qualitative result of the memory model training in Boxing. "
                        + _MEMORY.format(apostrophe="'"), (
        "The stochastic memory models was able to learn Boxing’s dynamics. Fig. 57 shows that the stochastic model "
        "generates very sharp and accurate predictions that model agents movement and punches really well. The agents "
        "does not disappear like in Sokoban and actions are smooth.",)),
    "5.8": ThesisFigure("5.5.1", f"Qualitative result of the model training in Sokoban. {_ROLLOUT}", (
        "PlaNet did not capture Sokoban dynamics too. In the figure below (Fig. 58) future predictions are blurred, "
        "multiple agents appear and other artifacts, like changing block type, are present.",)),
    "5.9": ThesisFigure("5.6.1", f"Qualitative result of the model training in Boxing. {_ROLLOUT}", (
        "It did not start to work out of the box of course. Fig. 59 shows that future predictions turn into a blurry "
        "blob, where it is not possible to distinguish one player from another.",)),
    "5.10": ThesisFigure("5.6.4", f"Qualitative result of the model training in Boxing. {_ROLLOUT}", (
        "In case of Boxing, it helped to model boxers moves and actions more accurately. The best free nats turned out "
        "to be 12. Fig. 510 shows final result.",)),
    "5.11": ThesisFigure("5.6.5", f"Qualitative result of the model training in Freeway. {_ROLLOUT}", (
        "The same random search procedure was applied to the Freeway environment described earlier. Fig. 511 shows "
        "final result.",
        "Despite really good future observations prediction the agent failed to solve the task.")),
}


def thesis_says(figure: str) -> str:
    """The thesis's words on ``figure`` ("5.4" to "5.11") as a Markdown blockquote: what its
    section says about the figure, then the figure's caption, both quoted verbatim."""
    if figure not in FIGURES:
        raise ValueError(f"no figure {figure!r} of the thesis is drawn again here; known: {', '.join(FIGURES)}")
    found = FIGURES[figure]
    says = " … ".join(found.says)
    return (f"> **The thesis on its Fig. {figure.replace('.', '')}** (section {found.section}): \"{says}\"\n>\n"
            f"> *Its caption:* \"{found.caption}\"")


__all__ = ["ThesisFigure", "FIGURES", "thesis_says"]
