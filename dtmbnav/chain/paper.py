"""The source paper's reported figures (``docs/method.md`` §6), for tables printed beside ours."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperFigures:
    """One scene of the paper's Tables 1-2: 68 % / 95 % / max position error, m."""

    pdr: tuple[float, float, float]
    pf: tuple[float, float, float]
    reduction_95: float


#: Scene (scenario-name prefix) -> the paper's figures.
PAPER = {
    "park-loop": PaperFigures(pdr=(2.67, 9.19, 10.84), pf=(2.08, 5.41, 7.31), reduction_95=0.41),
    "street": PaperFigures(pdr=(9.70, 13.27, 15.41), pf=(6.50, 9.34, 11.21), reduction_95=0.30),
}


def paper_figures(scenario_name: str) -> PaperFigures | None:
    """The paper's figures for a scenario (by its name's scene prefix), if it has any."""
    for scene, figures in PAPER.items():
        if scenario_name.startswith(scene):
            return figures
    return None
