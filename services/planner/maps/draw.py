"""`fleet map show`: the graph drawn by layer (paper 000 Fig. 2): the ground with roads, parking and
helipads, then each air layer, with no-fly zones shaded and obstacles outlined, and a 3D overview."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402

from common.domain.mapfile import MapSpec, load_map, resolve_map_path  # noqa: E402
from services.planner.graph.fleet_graph import FleetGraph  # noqa: E402

EDGE_COLOURS = {"drive": "0.35", "takeoff": "tab:green", "fly": "tab:blue", "land": "tab:orange"}
NODE_STYLE = {
    "land": dict(c="0.2", s=10, marker="o"),
    "waypoint": dict(c="tab:purple", s=6, marker="o"),
    "parking": dict(c="tab:red", s=28, marker="s"),
    "helipad": dict(c="gold", s=80, marker="H", edgecolors="k"),
    "air": dict(c="tab:blue", s=8, marker="o"),
}


def _layers(graph: FleetGraph) -> list[float]:
    air_z = sorted({round(float(z), 3) for z, k in zip(graph.pos[:, 2], graph.kinds, strict=True) if k == "air"})
    return [0.0, *air_z]


def _shade(ax, spec: MapSpec | None, z: float | None) -> None:
    if spec is None:
        return
    for zone in spec.no_fly:
        if z is None or zone.z[0] <= z <= zone.z[1]:
            ax.add_patch(Polygon(zone.polygon, closed=True, fc="tab:red", alpha=0.15, ec="tab:red", lw=0.5))
    for box in spec.obstacles:
        if z is None or box.min[2] <= z <= box.max[2] or z == 0.0:
            ax.add_patch(Rectangle(box.min[:2], box.max[0] - box.min[0], box.max[1] - box.min[1], fc="0.5", alpha=0.5))


def draw_map(graph: FleetGraph, out: Path, spec: MapSpec | None = None) -> None:
    """Write a PNG: one panel per layer (ground first) plus a 3D view of the whole graph."""
    if spec is None:
        path = resolve_map_path(graph.name)
        spec = load_map(path) if path.exists() else None
    layers = _layers(graph)
    fig = plt.figure(figsize=(5.5 * (len(layers) + 1), 5))
    z = graph.pos[:, 2]
    kinds = np.array(graph.kinds)
    for i, layer in enumerate(layers):
        ax = fig.add_subplot(1, len(layers) + 1, i + 1)
        _shade(ax, spec, layer)
        if layer == 0.0:
            on = (kinds != "air") & ~graph.airborne
            title = "ground: roads, parking (red), helipads (gold)"
        else:
            on = (kinds == "air") & (np.abs(z - layer) < 1e-3)
            title = f"air layer z = {layer:g} m"
        for (u, v), k in zip(graph.edges, graph.edge_kinds, strict=True):
            if on[u] and on[v]:
                ax.plot(*graph.pos[[u, v], :2].T, color=EDGE_COLOURS[k], lw=0.6, zorder=1)
            elif layer > 0 and k == "takeoff" and on[v]:
                ax.scatter(*graph.pos[v, :2], marker="^", c="tab:green", s=30, zorder=3)
        for kind, style in NODE_STYLE.items():
            sel = on & (kinds == kind)
            if sel.any():
                ax.scatter(graph.pos[sel, 0], graph.pos[sel, 1], zorder=2, label=f"{kind} ({int(sel.sum())})", **style)
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal")
        ax.legend(fontsize=6, loc="upper right")
    ax3 = fig.add_subplot(1, len(layers) + 1, len(layers) + 1, projection="3d")
    for (u, v), k in zip(graph.edges, graph.edge_kinds, strict=True):
        if u < v or k in ("takeoff", "land"):
            ax3.plot(*graph.pos[[u, v]].T, color=EDGE_COLOURS[k], lw=0.4)
    for kind, style in NODE_STYLE.items():
        sel = kinds == kind
        if sel.any():
            ax3.scatter(*graph.pos[sel].T, **{**style, "s": style["s"] / 2})
    ax3.set_title("3D: drive (grey), takeoff (green), fly (blue), land (orange)", fontsize=9)
    fig.suptitle(f"map {graph.name}: {graph.n_nodes} nodes, {graph.n_edges} edges; no-fly zones shaded red")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
