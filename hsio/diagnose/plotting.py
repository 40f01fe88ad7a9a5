"""The figures of the diagnosis reports (report.py, specimen_report.py, budget.py) drawn alike:
labelled axes with a light grid, the blocks of the honest scoring marked in time, saved at
100 dpi without a display."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt


def figure(rows: int, cols: int, size: tuple[float, float], **kwargs):
    """A new figure and its axes (matplotlib.pyplot.subplots)."""
    return plt.subplots(rows, cols, figsize=size, **kwargs)


def label(ax, xlabel: str | None = None, ylabel: str | None = None, title: str | None = None, legend: bool = True,
          loc: str = "best", which: str = "major") -> None:
    if xlabel:
        ax.set_xlabel(xlabel)
    if ylabel:
        ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    if legend:
        ax.legend(fontsize=8, loc=loc)
    ax.grid(alpha=0.3, which=which)


def mark_blocks(ax, marks: list[tuple[float, str]], fontsize: float = 8) -> None:
    """A dotted line at each time of ``marks`` with its text at the top (the fit, choose and score blocks)."""
    for t, text in marks:
        ax.axvline(t, color="k", ls=":", lw=1.0)
        ax.text(t, ax.get_ylim()[1], "  " + text, va="top", fontsize=fontsize)


def save(fig, path: str | Path, title: str | None = None) -> Path:
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
