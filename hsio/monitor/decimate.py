"""Decimation of the step histories sent to the page (docs/monitor.md section 4).

A page holds at most ``cap`` points per history, whatever the length of the run. Step i is shown
when i is a multiple of the stride; the stride starts at 1 and doubles whenever the steps shown
would exceed ``cap``. Between two doublings, an update sends only the new points (a stream of a
few rows); at a doubling, the page's history is replaced once by every second point it held.
Over a run of n steps the page thus receives about 2 n / stride_final + cap log2(n / cap) points
in all, never the whole record at each update.
"""

from __future__ import annotations

import numpy as np

DEFAULT_CAP = 3000


class Decimation:
    """Which steps a page shows, and what each update must send."""

    def __init__(self, cap: int = DEFAULT_CAP):
        if cap < 2:
            raise ValueError(f"cap must be at least 2 points, got {cap}")
        self.cap = cap
        self.stride = 1
        self.seen = 0  # steps 0 .. seen-1 have been considered

    def stride_for(self, n: int) -> int:
        stride = self.stride
        while -(-n // stride) > self.cap:
            stride *= 2
        return stride

    def update(self, n: int) -> tuple[str, np.ndarray]:
        """For ``n`` steps now recorded: ("replace", indices) when the page must be rebuilt,
        ("stream", indices) of the new points to append (possibly none)."""
        stride = self.stride_for(n)
        if stride != self.stride or n < self.seen:
            self.stride, self.seen = stride, n
            return "replace", np.arange(0, n, stride)
        first = -(-self.seen // stride) * stride  # the next multiple of the stride
        self.seen = n
        return "stream", np.arange(first, n, stride)
