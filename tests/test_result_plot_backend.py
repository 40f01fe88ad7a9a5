"""`Result.plot()` in a notebook or script: the user's matplotlib backend is left as it is (the
command line alone chooses Agg), and the figure is the caller's, not one pyplot keeps open."""

from __future__ import annotations

import importlib

import matplotlib
import matplotlib.pyplot as plt
from matplotlib.figure import Figure

import hsio


def test_plot_leaves_the_backend_and_pyplot_alone(tmp_path):
    structure = hsio.load_structure("structure_I")
    result = hsio.run_numerical(structure, hsio.synthetic_record(duration_s=0.2, dt=structure.dt, seed=1))
    previous = matplotlib.get_backend()
    matplotlib.use("svg")  # a user's choice, other than Agg
    try:
        from hsio import plots

        importlib.reload(plots)  # as when a session first imports it
        opened = plt.get_fignums()
        figures = [result.plot(tmp_path / f"run{k}.png") for k in range(3)]
        assert matplotlib.get_backend() == "svg"
        assert plt.get_fignums() == opened
    finally:
        matplotlib.use(previous)
    assert all(isinstance(f, Figure) for f in figures)
    assert all((tmp_path / f"run{k}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for k in range(3))
