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


def plot_flight_timeline(log_csv: str | Path, title: str = "") -> plt.Figure:
    """A flight log against time: the policy's raw action (dotted, in [-1, 1]) and the command sent (solid, m/s
    and rad/s), frame and pose ages against the 0.4 s staleness limit, battery, and the events (vertical lines,
    named)."""
    log = pd.read_csv(log_csv)
    fly = log[log.event.isna() | (log.event == "")]
    events = log[~(log.event.isna() | (log.event == ""))]
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7.0), sharex=True)
    for col, c in (("vx", "tab:blue"), ("vy", "tab:orange"), ("wz", "tab:green")):
        axes[0].plot(fly.t, fly[f"cmd_{col}"], color=c, label=f"sent {col}")
        if f"act_{col}" in fly:
            axes[0].plot(fly.t, fly[f"act_{col}"], color=c, ls=":", label=f"policy {col}")
    axes[0].set_ylabel("command (m/s, rad/s)")
    axes[0].legend(fontsize=7, ncol=3, loc="upper right", title="solid: sent; dotted: policy output in [-1, 1]",
                   title_fontsize=7)  # fmt: skip
    axes[1].plot(fly.t, fly.frame_age, label="frame age")
    axes[1].plot(fly.t, fly.pose_age, label="pose age")
    axes[1].axhline(0.4, color="tab:red", ls="--", lw=0.8, label="stale after 0.4 s")
    axes[1].set_ylabel("age (s)")
    axes[1].legend(fontsize=7, loc="upper right")
    if "battery" in log and log.battery.notna().any():
        axes[2].plot(log.t, log.battery, color="tab:purple")
    else:
        axes[2].text(0.5, 0.5, "the drone reports no battery", transform=axes[2].transAxes, ha="center", color="0.4")
    axes[2].set(ylabel="battery (%)", xlabel="time since takeoff (s)")
    for ax in axes:
        for _, e in events.iterrows():
            ax.axvline(e.t, color="0.4", lw=0.8)
    for _, e in events.iterrows():
        axes[0].annotate(str(e.event), (e.t, axes[0].get_ylim()[1]), fontsize=7, rotation=90, va="top", ha="right")
    fig.suptitle(title or f"flight log {Path(log_csv).name}", fontsize=10)
    fig.tight_layout()
    return fig


def replay(log_csv: str | Path, goal: tuple[float, float] | None = None, out: str | Path | None = None) -> Path:
    """Draw a flight log into one PNG (``out``, default beside the log): the path coloured by speed and the
    timeline of :func:`plot_flight_timeline`. ``goal`` (x, y) m is marked when given."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    log_csv = Path(log_csv)
    if not log_csv.is_file():
        raise FileNotFoundError(f"flight log {log_csv} does not exist")
    try:
        log = pd.read_csv(log_csv)
    except (OSError, ValueError, pd.errors.ParserError) as e:
        raise ValueError(f"{log_csv} is not a readable flight log ({' '.join(str(e).split())[:120]})") from None
    need = {"t", "x", "y", "cmd_vx", "event", "frame_age", "pose_age"}
    if not need <= set(log.columns):
        raise ValueError(f"{log_csv} is not a flight log: columns {sorted(need - set(log.columns))} missing")
    out = Path(out) if out is not None else log_csv.with_suffix(".png")
    figs = [plot_flight(log_csv, goal if goal is not None else (np.nan, np.nan), title=log_csv.stem),
            plot_flight_timeline(log_csv)]  # fmt: skip
    images = []
    for fig in figs:
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        images.append(np.asarray(canvas.buffer_rgba())[..., :3])
        plt.close(fig)
    h = max(i.shape[0] for i in images)
    padded = [np.pad(i, ((0, h - i.shape[0]), (0, 0), (0, 0)), constant_values=255) for i in images]
    plt.imsave(out, np.concatenate(padded, axis=1))
    return out
