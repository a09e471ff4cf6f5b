"""The radios file and the `fleet gateway` / `fleet sim` commands: good files load and round-trip,
bad ones are InputErrors naming the file, the field and the problem."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from common.deploy.radios import (
    GatewayParams,
    LinkModel,
    dump_radios,
    load_radios,
    simulated_radios,
)
from common.errors import InputError
from services.cli import build_parser

GOOD = """
radios:
  r0:
    link: {budget_pps: 400, loss: 0.05}
    vehicles:
      cf1: {uri: "radio://0/80/2M/E7E7E7E7E1"}
      cf2: {uri: "radio://0/80/2M/E7E7E7E7E2"}
  r1:
    vehicles:
      cf3: {uri: "udp://127.0.0.1:19850", start: [0.5, 1.0, 0.0], yaw: 1.57}
gateway: {tick_hz: 50, landing: {blind_height: 0.8}}
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "radios.yaml"
    path.write_text(text)
    return path


def test_a_good_file_loads_with_defaults_and_round_trips(tmp_path: Path) -> None:
    spec = load_radios(_write(tmp_path, GOOD))
    assert spec.radios["r0"].link == LinkModel(budget_pps=400, loss=0.05)
    assert spec.radios["r1"].link == LinkModel()
    assert spec.radios["r1"].vehicles["cf3"].start == (0.5, 1.0, 0.0)
    assert spec.gateway.tick_hz == 50 and spec.gateway.landing.blind_height == 0.8
    assert spec.gateway.stale_s == GatewayParams().stale_s
    assert load_radios(_write(tmp_path, dump_radios(spec))) == spec
    sim = simulated_radios({f"v{i}": (float(i), 0.0, 0.0) for i in range(5)}, per_radio=2, ports=range(30000, 30005))
    assert list(sim.radios) == ["r0", "r1", "r2"] and list(sim.radios["r2"].vehicles) == ["v4"]
    assert sim.radios["r1"].vehicles["v3"].uri == "udp://127.0.0.1:30003"


@pytest.mark.parametrize("text, field, problem", [
    ("", "", "file is empty"),
    ("radios: [", "line 1", "invalid YAML"),
    ("radios: {}", "radios", "no radio"),
    ("radios: {r0: {vehicles: {}}}", "radios.r0.vehicles", "no vehicle"),
    ("radios: {r0: {vehicles: {a: {uri: 'udp://h:1', colour: 2}}}}", "radios[...].vehicles[...]", "unknown field"),
    ("radios: {r0: {link: {loss: 1.5}, vehicles: {a: {uri: 'udp://h:1'}}}}", "radios[...].link.loss", "< 1.0"),
    ("radios: {r0: {vehicles: {a: {uri: 'usb://0'}}}}", "radios.r0.vehicles.a", "URI scheme 'usb'"),
    ("radios: {r0: {vehicles: {a: {uri: 'udp://h'}}}}", "radios.r0.vehicles.a", "udp://<host>:<port>"),
    ("radios: {r0: {vehicles: {a/b: {uri: 'udp://h:1'}}}}", "radios.r0.vehicles.a/b", "plain key chunk"),
    ("radios: {r0: {vehicles: {a: {uri: 'udp://h:1'}, b: {uri: 'udp://h:1'}}}}", "radios.r0.vehicles.b",
     "already used by a"),
    ("radios: {r0: {vehicles: {a: {uri: 'udp://h:1'}}}, r1: {vehicles: {a: {uri: 'udp://h:2'}}}}",
     "radios.r1.vehicles.a", "already on radio r0"),
    ("radios: {r0: {vehicles: {a: {uri: 'radio://0/80/2M/E7E7E7E7E1'}, b: {uri: 'radio://1/80/2M/E7E7E7E7E2'}}}}",
     "radios.r0.vehicles", "several dongles"),
    ("radios: {r0: {vehicles: {a: {uri: 'udp://h:1'}}}}\ngateway: {tick_hz: 0}", "gateway.tick_hz", "> 0"),
    ("radios: {r0: {vehicles: {a: {uri: 'udp://h:1'}}}}\nmocap: {pos_std: -1}", "mocap.pos_std", ">= 0"),
])
def test_bad_files_name_the_field_and_the_problem(tmp_path: Path, text: str, field: str, problem: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as err:
        load_radios(path)
    assert err.value.source == str(path) and err.value.field == field and problem in err.value.problem


def _command(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(list(argv))


def test_commands_refuse_bad_input_before_starting(tmp_path: Path) -> None:
    good = _write(tmp_path, GOOD)
    args = _command("gateway", "--config", str(good), "--radio", "r7")
    with pytest.raises(InputError, match="no radio 'r7'"):
        args.handler(args)
    args = _command("gateway", "--config", str(good), "--radio", "r0", "--radio", "r7")
    with pytest.raises(InputError, match="no radio 'r7'"):
        args.handler(args)
    args = _command("gateway", "--config", str(good), "--radio", "r0", "--radio", "r1", "--instance", "gw")
    with pytest.raises(InputError, match="several radios' are named after their radios"):
        args.handler(args)
    args = _command("sim", "--config", str(good), "--truth-hz", "0")
    with pytest.raises(InputError, match="must be positive"):
        args.handler(args)
    args = _command("sim", "--config", str(good), "--thrust-spread", "0.7")
    with pytest.raises(InputError, match="below 0.5"):
        args.handler(args)
    args = _command("sim", "--config", str(good), "--priority", "25")
    with pytest.raises(InputError, match="0 to 19"):
        args.handler(args)
    args = _command("gateway", "--config", str(tmp_path / "missing.yaml"), "--radio", "r0")
    with pytest.raises(InputError, match="cannot read"):
        args.handler(args)
    assert _command("gateway", "--config", str(good), "--radio", "r0").instance is None  # -> the radio's name
