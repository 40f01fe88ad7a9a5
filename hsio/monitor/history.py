"""The step histories the monitor keeps in memory, bounded however long the run (docs/monitor.md
section 4).

Two stores of the same float columns, filled as the steps are read from the record:

* the recent window: the last ``window`` steps (at least) at full resolution, for the newest
  step, the spectrum of the end-of-step errors and the control mode of the recent controller
  samples;
* the thinned history: every ``stride``-th step since the first (row 0, stride, 2 stride, ...),
  the stride a power of two doubled whenever more than ``cap`` rows would be kept, then every
  second row dropped. These are the rows of :class:`hsio.monitor.decimate.Decimation` with the
  same cap, so a page whose cap is at most ``cap`` finds each row it shows here (its stride, a
  power of two, is then a multiple of this one).

Memory: columns x (2 window + cap + window) floats at most, whatever the number of steps.
"""

from __future__ import annotations

import numpy as np

WINDOW = 4096  # steps kept whole
CAP = 6000  # rows of the thinned history (twice a page's default cap)


class History:
    """Float columns ``names`` of the steps appended so far, bounded (see the module's text)."""

    def __init__(self, names, window: int = WINDOW, cap: int = CAP):
        if window < 1 or cap < 2:
            raise ValueError(f"window must be at least 1 step and cap at least 2 rows, got {window}, {cap}")
        self.names = list(names)
        self._index = {name: i for i, name in enumerate(self.names)}
        self.window, self.cap = window, cap
        self.n = 0  # rows appended in all
        self.stride = 1
        self._recent = np.full((len(self.names), 2 * window), np.nan)
        self._used = 0  # rows held in _recent: rows n - _used .. n - 1
        self._thinned = np.full((len(self.names), 0), np.nan)  # rows 0, stride, 2 stride, ...

    @property
    def nbytes(self) -> int:
        return self._recent.nbytes + self._thinned.nbytes

    def append(self, block: np.ndarray) -> None:
        """Append the rows of ``block`` (columns x rows, in the order of ``names``)."""
        for start in range(0, block.shape[1], self.window):
            self._append(block[:, start: start + self.window])

    def _append(self, block: np.ndarray) -> None:
        m = block.shape[1]
        if self._used + m > self._recent.shape[1]:  # keep the last `window` rows, at the front
            keep = min(self._used, self.window)
            self._recent[:, :keep] = self._recent[:, self._used - keep: self._used]
            self._used = keep
        self._recent[:, self._used: self._used + m] = block
        self._used += m
        first = (-self.n) % self.stride  # the first row of the block on the stride
        self._thinned = np.concatenate([self._thinned, block[:, first::self.stride]], axis=1)
        self.n += m
        while self._thinned.shape[1] > self.cap:
            self._thinned = self._thinned[:, ::2].copy()
            self.stride *= 2

    # -- reading -----------------------------------------------------------------------------
    @property
    def recent_start(self) -> int:
        """The row of the first step held at full resolution."""
        return self.n - min(self._used, self.window)

    def recent(self, name: str) -> np.ndarray:
        """Column ``name`` over the last ``window`` steps (all of them while there are fewer)."""
        return self._recent[self._index[name], self._used - (self.n - self.recent_start): self._used]

    def last(self, name: str) -> float:
        """Column ``name`` at the newest step (NaN before the first)."""
        return float(self._recent[self._index[name], self._used - 1]) if self.n else float("nan")

    def take(self, rows: np.ndarray, names=None) -> dict[str, np.ndarray]:
        """Columns ``names`` (default: all) at ``rows`` (row numbers from 0); each must be a recent
        row or one on the stride, else ValueError."""
        rows = np.asarray(rows, dtype=np.int64)
        names = self.names if names is None else names
        if rows.size and (rows.min() < 0 or rows.max() >= self.n):
            raise ValueError(f"rows {rows.min()}..{rows.max()} are not all among the {self.n} steps read")
        held_from = self.n - self._used
        recent = rows >= held_from
        thinned = ~recent
        if np.any(rows[thinned] % self.stride):
            raise ValueError(f"row {rows[thinned][rows[thinned] % self.stride != 0][0]} is neither recent nor on "
                             f"the stride {self.stride} of the kept history")
        out = {}
        for name in names:
            i = self._index[name]
            values = np.empty(rows.size)
            values[recent] = self._recent[i, rows[recent] - held_from]
            values[thinned] = self._thinned[i, rows[thinned] // self.stride]
            out[name] = values
        return out
