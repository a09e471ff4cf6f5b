"""The router's hop on the hot path (issue 15; DESIGN.md, "Hot path": peer-to-peer transport "when
measurements show it pays"): a motion-capture frame of `--bodies` bodies at 100 Hz from one process
to `--subscribers` processes, each taking it in its event loop as the executors do
(`common.bus.pubsub.subscribe`), through the router (every fleet process is a client of it, which
is where access control is enforced: docs/security.md), over direct peer links (the publisher
listens, the subscribers connect to it), or over those with each frame in a shared-memory buffer
(`zenoh.shm`), or through a router in a busy process: one that also subscribes to the frames in
Python and runs Python work besides (as the soak's process did, with the mission runner and its
ground-truth judge, before the router got a process of its own: docs/bus.md). `--load N` runs N
busy processes beside it (a loaded machine). Prints, per transport, the latency from the frame's
stamp to its arrival in each subscriber's loop and the CPU of each process; saves a PNG.

    python -m bench.router_hop [--bodies 80] [--subscribers 2] [--seconds 20] [--load 0] [--warmup 300]
                               [--transports router,peer,shm,busy-router]
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import json
import resource
import subprocess
import sys
import threading
import time
from collections.abc import Callable

import zenoh
import zenoh.shm

from bench.tables import bench_parser, format_table, new_figure, save_figure
from common.bus.messages import Codec, FramePose, PoseFrame
from common.bus.pubsub import Publisher, encode_message, subscribe
from common.bus.session import InProcessRouter, ZenohConfig, free_tcp_endpoint, open_session

KEY = "bench/frame"
TRANSPORTS = ("router", "peer", "shm", "busy-router")
"""Through the router; direct peer links; direct peer links with the frames in shared memory;
through a router whose process runs Python besides (`busy_listener`)."""
BUSY_WORK_S = 0.05
"""s of Python work at a time in the busy router's process, each followed by as long idle."""
SHM_POOL = 1 << 22
"""Bytes of the publisher's shared-memory pool."""
SETTLE_S = 1.5
"""s the publisher waits for the subscribers' declarations before it publishes."""
WARMUP = 300
"""Frames published before the measured ones by default (`--warmup`; 3 s: every process started
and connected, the routes settled)."""
HANG_S = 420.0
"""s past its run after which a publisher or subscriber process is taken to hang: a guard, not a
budget. The suite runs this benchmark in its compute lane at idle CPU priority, which gets only
what the flights leave idle: with 60 s, a CI run on a slow hour timed the shared-memory publisher
out (its 4 s of frames took over a minute to get the CPU)."""


def cpu_s() -> float:
    """This process's CPU time so far (s)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def config(transport: str, endpoint: str, publisher: bool) -> ZenohConfig:
    """A client of the router at `endpoint`, or a peer listening there (the publisher) or connecting to it."""
    if transport in ("router", "busy-router"):
        return ZenohConfig.client(endpoint)
    link = {"listen": (endpoint,)} if publisher else {"connect": (endpoint,)}
    return ZenohConfig(mode="peer", extra={"transport/shared_memory/enabled": transport == "shm"}, **link)


def frame_sender(session: zenoh.Session, transport: str) -> Callable[[PoseFrame], None]:
    """Puts a frame: encoded as the fleet's publishers do; with "shm", into a shared-memory buffer."""
    if transport != "shm":
        return Publisher(session, KEY, PoseFrame).put
    codec, publisher = Codec(PoseFrame), session.declare_publisher(KEY)
    provider = zenoh.shm.ShmProvider.default_backend(SHM_POOL)

    def put(frame: PoseFrame) -> None:
        data = encode_message(codec, frame)
        buf = provider.alloc(len(data), zenoh.shm.BlockOn(zenoh.shm.GarbageCollect()))
        buf[:len(data)] = data
        publisher.put(buf)

    return put


def publish(transport: str, endpoint: str, seconds: float, bodies: int, warmup: int) -> dict:
    """`warmup` frames, then frames at 100 Hz for `seconds`; this process's CPU share over those."""
    session = open_session(config(transport, endpoint, publisher=True))
    put = frame_sender(session, transport)
    time.sleep(SETTLE_S)
    due, total = time.monotonic(), warmup + round(100 * seconds)
    start = cpu_s()
    for seq in range(total):
        if seq == warmup:
            start = cpu_s()
        poses = [FramePose(f"cf{i:02d}", 0.1 * i, 0.2, 0.3, 0.0) for i in range(bodies)]
        put(PoseFrame(t=time.time(), seq=seq, poses=poses))
        due += 0.01
        time.sleep(max(due - time.monotonic(), 0.0))
    share = (cpu_s() - start) / seconds
    time.sleep(0.5)
    session.close()
    return {"process": "publisher", "cpu": share, "frames": total - warmup}


def receive(transport: str, endpoint: str, seconds: float, warmup: int) -> dict:
    """Every frame's latency after the `warmup` ones into this process's event loop; its CPU share."""
    session = open_session(config(transport, endpoint, publisher=False))
    latencies: list[float] = []

    async def main() -> float:
        sub = subscribe(session, KEY, PoseFrame)
        start, last = None, warmup + round(100 * seconds) - 1
        heard = False
        while True:
            try:  # (the first frame: however late the publisher gets the CPU, `HANG_S`)
                frame, _key = await asyncio.wait_for(sub.recv(), warmup / 100 + SETTLE_S + 5.0 if heard else HANG_S)
            except TimeoutError:  # the publisher is done (its last frames lost)
                break
            heard = True
            if frame.seq < warmup:
                continue
            start = cpu_s() if start is None else start
            latencies.append(time.time() - frame.t)
            if frame.seq >= last:
                break
        return (cpu_s() - start) / seconds if start is not None else 0.0

    share = asyncio.run(main())
    session.close()
    latencies.sort()
    n = len(latencies)
    at = (lambda q: 1e3 * latencies[min(int(q * n), n - 1)]) if n else (lambda q: float("nan"))
    return {"process": "subscriber", "cpu": share, "frames": n, "p50_ms": at(0.5), "p99_ms": at(0.99),
            "max_ms": at(1.0)}


def busy_listener(endpoint: str, done: threading.Event) -> int:
    """Until `done`: this process (the busy router's) decodes every frame in a subscriber of its own
    and runs pure-Python work, `BUSY_WORK_S` at a time with as long idle between; frames heard."""
    session = open_session(ZenohConfig.client(endpoint))
    codec, heard = Codec(PoseFrame), [0]

    def on_frame(sample: zenoh.Sample) -> None:
        codec.decode(sample.payload.to_bytes())
        heard[0] += 1

    sub = session.declare_subscriber(KEY, on_frame)
    while not done.is_set():
        until = time.monotonic() + BUSY_WORK_S
        while time.monotonic() < until:
            sum(i * i for i in range(200))
        done.wait(BUSY_WORK_S)
    sub.undeclare()
    session.close()
    return heard[0]


def measure(transport: str, subscribers: int, seconds: float, bodies: int, load: int, warmup: int) -> list[dict]:
    """One run: the publisher, the subscribers and `load` busy processes; the router (when used) in
    this process, whose CPU share is then the router's (with "busy-router", its Python work's too)."""
    router = InProcessRouter(free_tcp_endpoint()) if transport in ("router", "busy-router") else None
    endpoint = router.endpoint if router is not None else free_tcp_endpoint()
    me = [sys.executable, "-m", "bench.router_hop", "--transport", transport, "--endpoint", endpoint,
          "--seconds", str(seconds), "--warmup", str(warmup)]
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        start, t0 = cpu_s(), time.monotonic()
        pub = subprocess.Popen([*me, "--role", "publisher", "--bodies", str(bodies)], stdout=subprocess.PIPE, text=True)
        subs = [subprocess.Popen([*me, "--role", "subscriber"], stdout=subprocess.PIPE, text=True)
                for _ in range(subscribers)]
        done = threading.Event()
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            busy = pool.submit(busy_listener, endpoint, done) if transport == "busy-router" else None
            try:
                rows = [json.loads(p.communicate(timeout=seconds + HANG_S)[0]) for p in [pub, *subs]]
            finally:
                done.set()
        if busy is not None:
            rows.append({"process": "busy listener", "frames": busy.result()})  # (its CPU: the router row's)
        if router is not None:
            rows.append({"process": "router", "cpu": (cpu_s() - start) / (time.monotonic() - t0)})
    finally:
        for hog in hogs:
            hog.kill()
        if router is not None:
            router.close()
    return [{"transport": transport, **row} for row in rows]


def main() -> None:
    parser = bench_parser(__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=80)
    parser.add_argument("--subscribers", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--load", type=int, default=0, help="busy processes beside the measurement")
    parser.add_argument("--warmup", type=int, default=WARMUP, help="frames published before the measured ones")
    parser.add_argument("--transports", default=",".join(TRANSPORTS), help="which, comma-separated")
    # the benchmark's own processes:
    parser.add_argument("--role", choices=["publisher", "subscriber"], help=argparse.SUPPRESS)
    parser.add_argument("--transport", choices=TRANSPORTS, help=argparse.SUPPRESS)
    parser.add_argument("--endpoint", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "publisher":
        print(json.dumps(publish(args.transport, args.endpoint, args.seconds, args.bodies, args.warmup)))
        return
    if args.role == "subscriber":
        print(json.dumps(receive(args.transport, args.endpoint, args.seconds, args.warmup)))
        return
    transports = [t for t in TRANSPORTS if t in args.transports.split(",")]
    rows = [row for transport in transports for row in measure(transport, args.subscribers, args.seconds,
                                                               args.bodies, args.load, args.warmup)]
    print(f"{args.bodies} bodies at 100 Hz to {args.subscribers} subscriber processes, {args.seconds:.0f} s, "
          f"{args.load} busy processes beside")
    print(format_table(["transport", "process", "frames", "latency p50/p99/max ms", "CPU %"],
                       [[r["transport"], r["process"], r.get("frames", "-"),
                         f"{r['p50_ms']:.2f}/{r['p99_ms']:.2f}/{r['max_ms']:.1f}" if "p50_ms" in r else "-",
                         f"{100 * r['cpu']:.1f}" if "cpu" in r else "-"] for r in rows]))
    fig, (ax,) = new_figure()
    for k, transport in enumerate(transports):
        subs = [r for r in rows if r["transport"] == transport and r["process"] == "subscriber"]
        for j, q in enumerate(("p50_ms", "p99_ms")):
            ax.bar(k * 3 + j, max(r[q] for r in subs), label=f"{transport} {q[:3]}")
    ax.set(ylabel="ms (worst subscriber)", title="frame latency: router hop vs peer link", xticks=[])
    ax.legend(fontsize=7)
    print(f"saved {save_figure(fig, args.out, 'router_hop')}")


if __name__ == "__main__":
    main()
