"""Flight plots for deployment (notebook 09): the path coloured by speed (as the paper's Fig. 12)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd


def plot_flight(
    log_csv: str | Path, goal: tuple[float, float], title: str = "", goal_radius: float = 0.5
) -> plt.Figure:
    """Top-down path of a flight log (:class:`omcrl.deploy.loop.ControlLoop`), coloured by ground speed (m/s).

    The goal is a star with the arrival circle; the event that ended the flight is in the title.
    """
    log = pd.read_csv(log_csv)
    fly = log[log.event.isna() | (log.event == "")].dropna(subset=["x", "y"])
    end = log.event.dropna()
    x, y, t = fly.x.to_numpy(), fly.y.to_numpy(), fly.t.to_numpy()
    speed = np.hypot(np.gradient(x, t), np.gradient(y, t)) if len(t) > 2 else np.zeros(len(x))
    fig, ax = plt.subplots(figsize=(5.2, 4.6))
    sc = ax.scatter(x, y, c=speed, cmap="viridis", s=14)
    ax.plot(x, y, color="0.7", lw=0.8, zorder=0)
    ax.plot(*goal, "*", color="tab:red", ms=14, label="goal")
    ax.add_patch(plt.Circle(goal, goal_radius, fill=False, ls="--", color="tab:red"))
    if len(x):
        ax.plot(x[0], y[0], "o", color="k", label="start")
    fig.colorbar(sc, ax=ax, label="speed (m/s)")
    reason = ", ".join(e for e in end if e and e != "land")
    ax.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=f"{title} ({reason or 'flight'})")
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return fig
