"""`fleet sim --config RADIOS` as a process (issue 14): every vehicle of the radios file is served at
its `udp://` URI, and any cflib client connects to it (here cflib's own `SyncCrazyflie` and
`SyncLogger`, no project code on the client side)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import cflib.crtp
from cflib.crazyflie import Crazyflie
from cflib.crazyflie.log import LogConfig
from cflib.crazyflie.syncCrazyflie import SyncCrazyflie
from cflib.crazyflie.syncLogger import SyncLogger

from common.bus.session import InProcessRouter
from common.deploy.compose import interpolate
from common.deploy.radios import free_udp_ports, load_radios

REPO = Path(__file__).resolve().parents[1]


def _wait_served(uri: str, sim: subprocess.Popen) -> None:
    """Until the process (importing, then binding its UDP ports) answers cflib's scan byte at `uri`."""
    host, port = uri.removeprefix("udp://").split(":")
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.settimeout(0.2)
    deadline = time.monotonic() + 30.0
    try:
        while time.monotonic() < deadline and sim.poll() is None:
            probe.sendto(b"\xff", (host, int(port)))
            try:
                probe.recvfrom(16)
                return
            except OSError:
                time.sleep(0.1)
    finally:
        probe.close()


def test_fleet_sim_serves_the_radios_file_to_any_cflib_client(tmp_path: Path) -> None:
    text = (REPO / "deploy" / "radios-town.yaml").read_text()
    for k, port in enumerate(free_udp_ports(8)):  # the shipped file's fixed ports may be taken here
        text = text.replace(f":{19850 + k}\n", f":{port}\n")
    radios = tmp_path / "radios.yaml"
    radios.write_text(interpolate(text, {"SIM_HOST": "127.0.0.1"}))
    uris = [v.uri for r in load_radios(radios).radios.values() for v in r.vehicles.values()]
    with InProcessRouter() as router:
        sim = subprocess.Popen([sys.executable, "-m", "services.cli", "sim", "--config", str(radios), "--connect",
                                router.endpoint], cwd=REPO, env=os.environ.copy(), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
        try:
            cflib.crtp.init_drivers()
            _wait_served(uris[-1], sim)
            for uri in (uris[0], uris[-1]):
                with SyncCrazyflie(uri, cf=Crazyflie(rw_cache=None)) as scf:
                    config = LogConfig("t", 100)
                    config.add_variable("pm.vbatMV", "uint16_t")
                    with SyncLogger(scf, config) as logger:
                        _ts, data, _ = next(iter(logger))
                    assert 3000 < data["pm.vbatMV"] < 4300
        finally:
            sim.terminate()
            out = sim.communicate(timeout=10)[0]
    assert sim.returncode == 0, out[-2000:]
