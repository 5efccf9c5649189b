"""The figures of a job's outputs (a sweep's summary, a tuning's folder): made, saved and listed one way.

::

    fig = new_figure((6.4, 3.6))
    ax = fig.subplots()
    ...
    paths = save_figure(fig, folder / "tune_history")          # tune_history.png and tune_history.svg
    listed = JobFigure(file="tune_history.png", caption="...")  # what summary.json / tune.json list

Figures are drawn headless (the Agg canvas, no pyplot state), with a constrained
layout, and saved by the project's one :func:`analysis.simulation.figures.save_figure` (laid
out once, without dates or tool stamps: the same numbers give the same files).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from analysis.results import JsonResult

__all__ = ["JobFigure", "new_figure", "save_figure", "FIGURE_FORMATS"]

#: The formats every job figure is written in (the reports show the PNG).
FIGURE_FORMATS = ("png", "svg")


@dataclass(frozen=True)
class JobFigure(JsonResult):
    """One figure of a job's outputs: its PNG file name (an SVG beside it) and its caption."""

    file: str
    caption: str


def new_figure(size: tuple[float, float]):
    """A matplotlib figure of ``size`` inches on the Agg canvas, with a constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, stem: Path, formats=FIGURE_FORMATS) -> list[Path]:
    """Write ``fig`` as ``stem.<format>`` for each format (the folder is made); return the paths written.

    :func:`analysis.simulation.figures.save_figure` writes them: laid out once for every format, without dates or tool
    stamps (imported here, when a figure is saved, since it loads pyplot).
    """
    from analysis.simulation.figures import save_figure as save
    stem = Path(stem)
    return save(fig, stem.parent, stem.name, formats)
