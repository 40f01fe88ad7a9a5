"""PNG plots of a run: displacement histories HS vs NS, force-displacement loops, tracking error."""

from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib.pyplot as plt  # the backend is the user's; the command line chooses Agg (hsio.entry)
import numpy as np
from matplotlib.figure import Figure

from hsio.recording import column


def displacement_histories(path: Path, t, u_hs, t_ns, u_ns, dof_names, title: str = "", units=None) -> Path:
    """Displacement of each DOF, HS against NS, with the difference underneath; ``units`` per DOF
    ("mm", or "rad" for a rotation; default mm)."""
    n = len(dof_names)
    units = units or ["mm"] * n
    fig, axes = plt.subplots(2 * n, 1, figsize=(10, 3.2 * n + 1), sharex=True,
                             gridspec_kw={"height_ratios": [3, 1] * n})
    for k, name in enumerate(dof_names):
        ax, ax_err = axes[2 * k], axes[2 * k + 1]
        if u_ns is not None:
            ax.plot(t_ns, u_ns[:, k], color="0.55", lw=2.2, label="NS (numerical)")
        ax.plot(t, u_hs[:, k], color="C0", lw=1.0, label="HS (hybrid)")
        ax.set_ylabel(f"{name} {'rotation' if units[k] == 'rad' else 'displacement'} ({units[k]})")
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


def hysteresis_loops(path: Path, disp, force, actuator_names, ns_disp=None, ns_force=None, units=None) -> Path:
    """Measured force against measured displacement for each channel (NS behind, in grey);
    ``units`` per channel (displacement, force): ("mm", "kN"), or ("rad", "kN mm") on a rotation."""
    n = len(actuator_names)
    units = units or [("mm", "kN")] * n
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 4.5), squeeze=False)
    for j, name in enumerate(actuator_names):
        ax = axes[0, j]
        if ns_disp is not None:
            ax.plot(ns_disp[:, j], ns_force[:, j], color="0.6", lw=2.0, label="NS")
        ax.plot(disp[:, j], force[:, j], color="C0", lw=0.8, label="HS measured")
        rotation = units[j][0] == "rad"
        ax.set_xlabel(f"{'rotation' if rotation else 'displacement'} ({units[j][0]})")
        ax.set_ylabel(f"{'moment' if rotation else 'force'} ({units[j][1]})")
        ax.set_title(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Force-displacement loops")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def tracking_error(path: Path, t, targets, measured, actuator_names, resolution_mm: float | None = None,
                   units=None) -> Path:
    """Target minus measured displacement at the end of each step, per channel; ``units`` per
    channel ("mm", or "rad" on a rotation: no resolution lines there, the transducers read mm)."""
    n = len(actuator_names)
    units = units or ["mm"] * n
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n + 0.8), sharex=True, squeeze=False)
    for j, name in enumerate(actuator_names):
        ax = axes[j, 0]
        err = targets[:, j] - measured[:, j]
        rms = float(np.sqrt(np.mean(err[1:] ** 2))) if len(err) > 1 else 0.0
        ax.plot(t, err, color="C2", lw=0.7)
        if resolution_mm and units[j] == "mm":
            for s in (-1, 1):
                ax.axhline(s * resolution_mm, color="0.5", ls="--", lw=0.7)
        ax.set_ylabel(f"{name} error ({units[j]})")
        ax.set_title(f"{name}: RMS {rms:.4g} {units[j]}" if units[j] != "mm" else f"{name}: RMS {rms:.4f} mm",
                     fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle("Tracking error: target - measured at the end of each step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def last_samples(path: Path, committed: dict, uncommitted: dict, stop: dict, actuator_names, units=None) -> Path:
    """The controller-rate samples before a stop in the middle of a step (docs/safety.md
    section 1): per channel, command and measurement of the last committed steps (``committed``,
    columns of the ``samples`` table) and of the unfinished step (``uncommitted``, its
    ``uncommitted_samples`` rows), shaded, up to the stop's lab time (``stop``: a row of
    ``uncommitted_steps``), marked."""
    n = len(actuator_names)
    units = units or ["mm"] * n
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n + 0.8), sharex=True, squeeze=False)
    t_stop = stop["stop_lab_time_s"]
    for j, name in enumerate(actuator_names):
        ax = axes[j, 0]
        for rows, labelled in ((committed, True), (uncommitted, False)):
            if not rows or not len(rows.get("lab_time_s", ())):
                continue
            t = rows["lab_time_s"]
            ax.plot(t, rows[column("cmd", name)], color="C0", lw=0.9, label="command" if labelled else None)
            ax.plot(t, rows[column("disp", name)], color="C3", lw=0.9, label="measured" if labelled else None)
        if uncommitted and len(uncommitted.get("lab_time_s", ())):
            ax.axvspan(float(np.nanmin(uncommitted["lab_time_s"])), float(np.nanmax(uncommitted["lab_time_s"])),
                       color="0.85", zorder=0)
        if np.isfinite(t_stop):
            ax.axvline(t_stop, color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"{name} ({units[j]})")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel("lab time (s)")
    cause = textwrap.shorten(str(stop.get("cause", "")), 240)
    fig.suptitle("\n".join([f"Samples before the stop in step {int(stop['step'])} (shaded: that step, not committed; "
                             "dashed: the stop)", *textwrap.wrap(cause, 120)]), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def control_modes(path: Path, hs, incidence=None) -> Path:
    """Per element: its displacement (E u, ``incidence`` E of the structure: the drift of an
    element between two DOFs; None: u at the element's DOF) with FC steps shaded, and the secant
    stiffness against the switching thresholds (docs/method.md section 5)."""
    n = len(hs.element_dofs)
    E = np.asarray(incidence, dtype=float) if incidence is not None else None
    fig, axes = plt.subplots(2 * n, 1, figsize=(10, 4.4 * n + 0.8), sharex=True, squeeze=False)
    th = hs.thresholds
    for j, d in enumerate(hs.element_dofs):
        ax, ax_k = axes[2 * j, 0], axes[2 * j + 1, 0]
        name = hs.dof_names[d]
        fc = hs.modes[:, d] == "force"
        u = hs.u[:, d] if E is None else hs.u @ E[j]
        between = [hs.dof_names[k] for k in np.flatnonzero(E[j] < 0)] if E is not None else []
        label = f"{hs.element_names[j]}: {name} - {between[0]}" if between else name
        ax.plot(hs.t, u, color="C0", lw=0.9, label="drift" if between else "displacement")
        ymin, ymax = ax.get_ylim()
        ax.fill_between(hs.t, ymin, ymax, where=fc, color="C3", alpha=0.15, step="mid", label="force control")
        ax.set_ylim(ymin, ymax)
        ax.set_ylabel(f"{label} (mm)")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
        switches = [s for s in hs.switches if s.dof == name]
        ax.set_title(f"{label}: {len(switches)} switches, {fc[1:].mean() * 100:.0f} % of steps in FC", fontsize=9, loc="left")
        on_force = th is not None and th["on"] == "force"  # the rule reads |R|: show it against R_f, R_d
        if on_force:
            ax_k.plot(hs.t, np.abs(hs.measured_force[:, j]), color="C2", lw=0.8, label="|restoring force|")
        else:
            ax_k.plot(hs.t, hs.secant[:, j], color="C2", lw=0.8, label="secant stiffness")
        if th is not None:
            up, down = ("R_f", "R_d") if on_force else ("K_f", "K_d")
            if th["upper"][j] is not None:  # None: kept in DC (e.g. the NS gate of the instruments rule)
                ax_k.axhline(th["upper"][j], color="C3", ls="--", lw=0.8, label=f"{up} (to FC)")
            else:
                ax_k.plot([], [], color="C3", ls="--", lw=0.8, label=f"{up}: none (kept in DC)")
            ax_k.axhline(th["lower"][j], color="C0", ls="--", lw=0.8, label=f"{down} (to DC)")
        ax_k.set_ylabel("|R| (kN)" if on_force else "k (kN/mm)")
        ax_k.legend(loc="upper right", fontsize=8)
        ax_k.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(f"Control mode per step ({hs.method})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def result_figure(result, reference=None, path: str | Path | None = None):
    """One figure of a :class:`hsio.result.Result`: displacement of each DOF (against
    ``reference``, e.g. NS) and the force-displacement loop of each experimental element."""
    n, m = len(result.dof_names), len(result.element_names)
    rows = max(n, m)
    # a Figure of its own, not kept by pyplot: a notebook's figures and backend are left as they are
    fig = Figure(figsize=(11, 2.8 * rows + 0.8))
    axes = fig.subplots(rows, 2, squeeze=False)
    for k, name in enumerate(result.dof_names):
        ax = axes[k, 0]
        if reference is not None:
            ax.plot(reference.t, reference.u[:, k], color="0.55", lw=2.0, label="reference")
        ax.plot(result.t, result.u[:, k], color="C0", lw=0.9, label=result.method)
        ax.set_ylabel(f"{name} ({result.unit_of_dof(k)})")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    for j, name in enumerate(result.element_names):
        ax = axes[j, 1]
        ax.plot(result.measured_displacement[1:, j], result.measured_force[1:, j], color="C1", lw=0.8)
        rotation = result.unit_of_dof(result.element_dofs[j]) == "rad"
        ax.set_xlabel(f"{name} {'rotation (rad)' if rotation else 'displacement (mm)'}")
        ax.set_ylabel("moment (kN mm)" if rotation else "force (kN)")
        ax.grid(alpha=0.3)
    for row in range(rows):
        if row >= n:
            axes[row, 0].set_visible(False)
        if row >= m:
            axes[row, 1].set_visible(False)
    axes[min(n, rows) - 1, 0].set_xlabel("time (s)")
    fig.suptitle(f"{result.structure}: {result.method}, {result.steps} steps")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
