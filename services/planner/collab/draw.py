"""Drawing maps and team plans with matplotlib (002 Fig. 5, Fig. 6)."""

from __future__ import annotations

import numpy as np
from matplotlib.lines import Line2D

from common.domain.team_plan import GoToLandmarkDyn, TeamPlan
from common.team.env import Env

CONTROLLER_COLORS = {
    "WallFollowing": "tab:blue",
    "GoToLandmarkStat": "tab:green",
    "GoToLandmarkDyn": "tab:red",
    "MetricTurn": "tab:orange",
    "MetricStep": "tab:orange",
    "Altitude": "tab:purple",
}


def draw_map(ax, env: Env) -> None:
    """Walls black, low obstacles grey by height, UGV-forbidden zones tinted, landmarks as stars."""
    h, w = env.shape
    extent = (0, w * env.resolution, 0, h * env.resolution)
    tops = np.where(np.isinf(env.heights), 3.0, env.heights)
    ax.imshow(tops, origin="lower", cmap="Greys", vmin=0, vmax=3.0, extent=extent, interpolation="nearest")
    ax.imshow(np.where(env.no_ugv, 1.0, np.nan), origin="lower", cmap="Blues", vmin=0, vmax=4, alpha=0.35,
              extent=extent, interpolation="nearest")
    for lm in env.landmarks:
        ax.plot(lm.x, lm.y, "*", color="gold", markersize=11, markeredgecolor="k")
    ax.set_aspect("equal")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])


def draw_plan(ax, plan: TeamPlan) -> None:
    """The drone's path coloured by controller, the UGV's in magenta, start and goal circled."""
    x, y, _ = plan.drone_start
    for step in plan.drone:
        ex, ey, _ = step.end
        color = CONTROLLER_COLORS.get(type(step.action).__name__, "k")
        ax.plot([x, ex], [y, ey], "-", color=color, linewidth=2)
        if isinstance(step.action, GoToLandmarkDyn):
            ax.plot(ex, ey, "o", color=color, markersize=3)
        x, y = ex, ey
    ux = [plan.ugv_start[0], *(s.end[0] for s in plan.ugv)]
    uy = [plan.ugv_start[1], *(s.end[1] for s in plan.ugv)]
    ax.plot(ux, uy, "-", color="magenta", linewidth=1.5, alpha=0.8)
    ax.plot(ux[0], uy[0], "s", color="magenta", markersize=7)
    for px, py in (plan.drone_start[:2], plan.goal[:2]):
        ax.plot(px, py, "o", markersize=14, markerfacecolor="none", markeredgecolor="b", markeredgewidth=2)
    used = {type(s.action).__name__ for s in plan.drone}
    handles = [Line2D([], [], color=c, linewidth=2, label=n) for n, c in CONTROLLER_COLORS.items() if n in used]
    handles.append(Line2D([], [], color="magenta", linewidth=1.5, label="UGV"))
    ax.legend(handles=handles, loc="upper right", fontsize=7, framealpha=0.9)
