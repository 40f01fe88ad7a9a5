"""PNG plots of a run: displacement histories HS vs NS, force-displacement loops, tracking error."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def displacement_histories(path: Path, t, u_hs, t_ns, u_ns, dof_names, title: str = "") -> Path:
    """Displacement of each DOF, HS against NS, with the difference underneath."""
    n = len(dof_names)
    fig, axes = plt.subplots(2 * n, 1, figsize=(10, 3.2 * n + 1), sharex=True,
                             gridspec_kw={"height_ratios": [3, 1] * n})
    for k, name in enumerate(dof_names):
        ax, ax_err = axes[2 * k], axes[2 * k + 1]
        if u_ns is not None:
            ax.plot(t_ns, u_ns[:, k], color="0.55", lw=2.2, label="NS (numerical)")
        ax.plot(t, u_hs[:, k], color="C0", lw=1.0, label="HS (hybrid)")
        ax.set_ylabel(f"{name} displacement (mm)")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
        if u_ns is not None:
            m = min(len(u_hs), len(u_ns))
            peak = max(np.max(np.abs(u_ns[:m, k])), 1e-12)
            ax_err.plot(t[:m], (u_hs[:m, k] - u_ns[:m, k]) / peak * 100, color="C3", lw=0.8)
            ax_err.set_ylabel("HS-NS (% peak)")
            ax_err.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title or "Displacement: hybrid vs numerical simulation")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def hysteresis_loops(path: Path, disp, force, actuator_names, ns_disp=None, ns_force=None) -> Path:
    """Measured force against measured displacement for each actuator (NS behind, in grey)."""
    n = len(actuator_names)
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 4.5), squeeze=False)
    for j, name in enumerate(actuator_names):
        ax = axes[0, j]
        if ns_disp is not None:
            ax.plot(ns_disp[:, j], ns_force[:, j], color="0.6", lw=2.0, label="NS")
        ax.plot(disp[:, j], force[:, j], color="C0", lw=0.8, label="HS measured")
        ax.set_xlabel("displacement (mm)")
        ax.set_ylabel("force (kN)")
        ax.set_title(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Force-displacement loops")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def tracking_error(path: Path, t, targets, measured, actuator_names, resolution_mm: float | None = None) -> Path:
    """Target minus measured displacement at the end of each step, per actuator."""
    n = len(actuator_names)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n + 0.8), sharex=True, squeeze=False)
    for j, name in enumerate(actuator_names):
        ax = axes[j, 0]
        err = targets[:, j] - measured[:, j]
        rms = float(np.sqrt(np.mean(err[1:] ** 2))) if len(err) > 1 else 0.0
        ax.plot(t, err, color="C2", lw=0.7)
        if resolution_mm:
            for s in (-1, 1):
                ax.axhline(s * resolution_mm, color="0.5", ls="--", lw=0.7)
        ax.set_ylabel(f"{name} error (mm)")
        ax.set_title(f"{name}: RMS {rms:.4f} mm", fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle("Tracking error: target - measured at the end of each step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
