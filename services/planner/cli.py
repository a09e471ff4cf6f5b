"""`fleet map ...`, `fleet plan`, `fleet validate`, `fleet replay-plan`, `fleet planner` (the
service): the planner's command-line face."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from common.bus.args import add_zenoh_args, lazy_handler
from common.errors import InputError


def _register_service(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("planner", help="run the planner service (zenoh queryable planner/plan)")
    add_zenoh_args(p, default_instance="planner")
    p.add_argument("--keep-failed", metavar="DIR",
                   help="write each request it could not plan to DIR (for `fleet replay-plan`)")
    p.set_defaults(handler=lazy_handler("services.planner.service:cmd_planner"))


def register(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser("map", help="check, draw, export or generate maps")
    msub = m.add_subparsers(dest="map_command", required=True, metavar="ACTION")
    p = msub.add_parser("check", help="validate a map; print node and edge counts per kind")
    p.add_argument("map")
    p.add_argument("--dt", type=float, help="also build the uniform-time-step graph with this step")
    p.set_defaults(handler=cmd_map_check)
    p = msub.add_parser("show", help="draw the graph by layer as a PNG")
    p.add_argument("map")
    p.add_argument("--out", default="map.png")
    p.set_defaults(handler=cmd_map_show)
    p = msub.add_parser("export", help="write the plan file's `graph` form as JSON")
    p.add_argument("map")
    p.add_argument("--out", default="graph.json")
    p.add_argument("--uniform", action="store_true", help="export the uniform-time-step graph")
    p.set_defaults(handler=cmd_map_export)
    p = msub.add_parser("generate", help="regenerate a shipped map's YAML")
    p.add_argument("name", choices=["town", "fig6", "grid125", "city934"])
    p.add_argument("--out", help="default maps/NAME.yaml")
    p.set_defaults(handler=cmd_map_generate)

    p = sub.add_parser("plan", help="plan collision-free paths and write a plan file")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--map", help="map name (maps/NAME.yaml) or path")
    src.add_argument("--movingai", help="a MovingAI .map grid")
    tasks = p.add_mutually_exclusive_group()
    tasks.add_argument("--scenario", help="scenario YAML (vehicle id -> start, goal)")
    tasks.add_argument("--random", type=int, metavar="N", help="N vehicles on random distinct spots")
    p.add_argument("--scen", help="MovingAI .scen file (with --movingai)")
    p.add_argument("--agents", type=int, default=10, help="first K agents of the .scen")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--planner", choices=["sipp", "ilp"], default="sipp")
    p.add_argument("--mu", type=float, default=0.5, help="energy weight of eq. 3, in [0, 1]")
    p.add_argument("--time-limit", type=float, default=30.0)
    p.add_argument("--uniform", action="store_true", help="plan on the uniform-time-step graph (always for ilp)")
    p.add_argument("--out", default="plan.json")
    p.set_defaults(handler=cmd_plan)

    p = sub.add_parser("validate", help="independently check a plan file")
    p.add_argument("plan")
    p.set_defaults(handler=cmd_validate)

    p = sub.add_parser("replay-plan", help="plan again a request the planner service kept (--keep-failed)")
    p.add_argument("request", help="a DIR/NNN-KIND.msgpack file of `fleet planner --keep-failed DIR`")
    p.set_defaults(handler=cmd_replay_plan)
    _register_service(sub)


def cmd_map_check(args: argparse.Namespace) -> int:
    from services.planner.maps.loading import load_graph

    for dt in [None] + ([args.dt] if args.dt else []):
        graph = load_graph(args.map, dt)
        nodes, edges = graph.counts()
        label = "base graph" if dt is None else f"uniform graph, dt = {dt:g} s"
        print(f"{graph.name} ({label}): {graph.n_nodes} nodes, {graph.n_edges} edges")
        print("  nodes: " + ", ".join(f"{k} {v}" for k, v in nodes.items()))
        print("  edges: " + ", ".join(f"{k} {v}" for k, v in edges.items()))
        conf = graph.conflicts
        n_pairs = sum(len(x) for x in conf.node_nodes) // 2
        print(f"  contact pairs: node-node {n_pairs}, edge-edge {conf.edge_pair_count()}")
        print(f"  W_max {graph.scale.w_max:.3f} J, t_max {graph.scale.t_max:.3f} s (at the vehicle's speeds)")
        if dt is not None:
            slow = graph.slowdown()
            print(f"  one step per edge: slow-down vs the kind's speed largest {slow.max(initial=0):.1%}, "
                  f"mean {slow.mean() if len(slow) else 0:.1%}")
    print("ok")
    return 0


def cmd_map_show(args: argparse.Namespace) -> int:
    from services.planner.maps.draw import draw_map
    from services.planner.maps.loading import load_graph

    graph = load_graph(args.map)
    draw_map(graph, Path(args.out))
    print(f"wrote {args.out}")
    return 0


def cmd_map_export(args: argparse.Namespace) -> int:
    import msgspec

    from services.planner.maps.loading import load_graph

    graph = load_graph(args.map, uniform=args.uniform)
    Path(args.out).write_bytes(msgspec.json.format(msgspec.json.encode(graph.to_plan_graph()), indent=1))
    print(f"wrote {args.out}: {graph.n_nodes} nodes, {graph.n_edges} edges")
    return 0


def cmd_map_generate(args: argparse.Namespace) -> int:
    from common.domain.mapfile import MAPS_DIR
    from services.planner.maps.generate import GENERATORS, to_yaml

    out = Path(args.out) if args.out else MAPS_DIR / f"{args.name}.yaml"
    out.write_text(to_yaml(GENERATORS[args.name]()))
    print(f"wrote {out}")
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    from common.domain.planfile import write_plan
    from services.planner.maps.loading import load_problem

    if not 0.0 <= args.mu <= 1.0:
        raise InputError("--mu", "", f"must be in [0, 1], got {args.mu}")
    if args.time_limit <= 0:
        raise InputError("--time-limit", "", "must be positive")
    problem = load_problem(args)
    from services.planner.registry import run_planner
    from services.planner.validate import validate_plan

    t0 = time.perf_counter()
    plan, result = run_planner(problem, args.planner, args.mu, args.time_limit, args.seed)
    if plan is None:
        who = f" (could not place {result.failed_vehicle})" if result.failed_vehicle else ""
        print(f"fleet plan: no plan{who}: {result.error}", file=sys.stderr)
        return 1
    report = validate_plan(plan)
    if not report.ok:
        print("fleet plan: the planner's result failed validation, not written:", file=sys.stderr)
        for line in report.errors[:20]:
            print(f"  {line}", file=sys.stderr)
        return 1
    write_plan(plan, args.out)
    gap = f", MIP gap {plan.mip_gap:.3%}" if plan.mip_gap is not None else ""
    print(
        f"{args.planner}: {len(plan.paths)} vehicles, cost {plan.cost:.4f}, planned in {plan.planning_time_s:.3f} s"
        f"{gap}, makespan {report.makespan:.1f} s, energy {report.energy:.1f} J "
        f"(total {time.perf_counter() - t0:.2f} s) -> {args.out}"
    )
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    from common.domain.planfile import read_plan
    from services.planner.validate import validate_plan

    plan = read_plan(args.plan)
    report = validate_plan(plan)
    print(report.summary())
    return 0 if report.ok else 1


def cmd_replay_plan(args: argparse.Namespace) -> int:
    """Plan a kept request again (`services/planner/failed_requests.py`): what it asked, and the
    planner's answer now; exit 0 if it planned, 1 if not."""
    from services.planner.failed_requests import read_request, warm_up
    from services.planner.registry import solve

    req = read_request(Path(args.request))
    what = (f"replan of {len(req.replan.base.paths)} vehicles from {req.replan.at:.1f} s around "
            f"{', '.join(req.replan.left) or 'none'}" if req.replan is not None else f"plan of {len(req.tasks)} vehicles")
    print(f"{args.request}: {what} on {req.map}, {req.planner}, time limit {req.time_limit:.2f} s")
    t0 = time.perf_counter()
    warm_up(req)
    print(f"warmed up in {time.perf_counter() - t0:.2f} s (the map's graph and tables, as a running planner has them)")
    t0 = time.perf_counter()
    reply = solve(req)
    took = time.perf_counter() - t0
    if reply.ok:
        print(f"planned in {took:.2f} s")
        return 0
    print(f"not planned ({took:.2f} s): {reply.error}")
    return 1
