"""The wheel app's portable C logic (firmware/wheels): its host tests, and its packet filter driven
with packets built here by hand, so that the bytes of firmware/wheels/PROTOCOL.md (version 2) are
checked from Python as well as from C, and with the gateway's own codec (`common.crazyflie.crtp`)
both ways. Builds into a temporary directory: nothing is written to the
tree. The tests that build are skipped when no C compiler or make is installed."""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from common.crazyflie import crtp

pytestmark = pytest.mark.compute

HOST = Path(__file__).resolve().parents[1] / "firmware" / "wheels" / "host"

needs_cc = pytest.mark.skipif(
    shutil.which("make") is None or (shutil.which("cc") is None and shutil.which("gcc") is None),
    reason="needs make and a C compiler (cc or gcc) to build firmware/wheels/host",
)

UP = 0xDE  # app channel header as cflib sends it (port 0x0D, channel 2, bits 3-2 set)
DOWN = 0xD2  # as the firmware sends it (bits 3-2 clear)
STATUS = struct.Struct("<BBIIIHHhhHB")  # version, type, echo_seq, received, uptime_ms, rejected,
# vbat_mv, wheel_left_mm_s, wheel_right_mm_s, setpoint_age_ms, flags
FLAG_WHEEL_WATCHDOG = 0x01
FLAG_ARMED = 0x10


def _make(build: Path, target: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["make", "-C", str(HOST), f"BUILD={build}", target], capture_output=True, text=True,
                          timeout=600, check=False)


def _wheels(left: int, right: int, version: int = 2) -> bytes:
    return bytes((UP,)) + struct.pack("<BBhh", version, 0x01, left, right)


def _request(seq: int) -> bytes:
    return bytes((UP,)) + struct.pack("<BBI", 2, 0x02, seq)


def _filter(build: Path, lines: list[str], *options: str) -> list[list[str]]:
    run = subprocess.run([str(build / "wheels_filter"), *options], input="\n".join(lines) + "\n",
                         capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    return [line.split() for line in run.stdout.splitlines()]


def _replies(out: list[list[str]]) -> dict[int, tuple[int, ...]]:
    replies = {}
    for t, kind, *rest in out:
        if kind == "reply":
            raw = bytes.fromhex(rest[0])
            assert raw[0] >> 4 == 0x0D and raw[0] & 0x03 == 2  # app channel, whatever bits 3-2
            replies[int(t)] = STATUS.unpack(raw[1:])
    return replies


def _outputs(out: list[list[str]]) -> dict[int, list[int]]:
    return {int(t): [int(v) for v in rest] for t, kind, *rest in out if kind == "out"}


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("wheels_host")
    made = _make(path, "all")
    assert made.returncode == 0, made.stdout + made.stderr
    return path


@needs_cc
def test_host_tests_pass(tmp_path: Path) -> None:
    made = _make(tmp_path, "test")
    assert made.returncode == 0, made.stdout + made.stderr
    assert " passed, 0 failed" in made.stdout and "wheels_filter: ok" in made.stdout


@needs_cc
def test_packet_filter_speaks_protocol_v2(build: Path) -> None:
    setpoint = bytes((0x3C,)) + struct.pack("<fffH", 0.0, 0.0, 0.0, 0)  # commander: never reaches the app
    too_long = _wheels(1, 1) + bytes(1)
    lines = [
        "0 set vbat 3870",
        f"0 set flags {FLAG_ARMED:#x}",
        f"10 {_wheels(100, -50).hex()}",
        f"20 {_request(2).hex()}",
        f"30 {_wheels(100, -50, version=1).hex()}",  # version 1: dropped, counted
        f"40 {too_long.hex()}",  # 7 bytes: dropped, counted
        f"50 {bytes((UP, 2, 0x09)).hex()}",  # unknown type
        f"60 {setpoint.hex()}",
        "70 ff",  # null packet
        "510",  # 500 ms after the last WHEELS: still driving
        "511",  # 501 ms: the watchdog stops the wheels
        f"600 {_request(9).hex()}",
        f"610 {_request(10).hex()}",
    ]
    out = _filter(build, lines)
    events = [(int(t), kind, *rest) for t, kind, *rest in out if kind != "out"]
    assert events[:1] == [(10, "wheels", "100", "-50")]
    assert (30, "rejected", "version") in events and (40, "rejected", "length") in events
    assert (50, "rejected", "type") in events
    assert (60, "ignored") in events and (70, "ignored") in events
    assert (511, "watchdog") in events and not any(e[1] == "watchdog" and e[0] < 511 for e in events)

    replies = _replies(out)
    # echo, received (this request included), uptime, rejected, vbat, wheels, setpoint age, flags
    assert replies[20] == (2, 0x81, 2, 2, 20, 0, 3870, 100, -50, 0xFFFF, FLAG_ARMED)
    assert replies[600] == (2, 0x81, 9, 6, 600, 3, 3870, 0, 0, 0xFFFF, FLAG_ARMED | FLAG_WHEEL_WATCHDOG)
    assert replies[610] == (2, 0x81, 10, 7, 610, 3, 3870, 0, 0, 0xFFFF, FLAG_ARMED)  # latched flag sent once

    outs = _outputs(out)
    # setpoint, then per motor dir, drive, in1, in2, pwm (DRV8833: IN1 = direction, IN2 = PWM)
    assert outs[10] == [100, -50, 1, 1000, 1, 0, 9000, -1, 500, 0, 0, 500]
    assert outs[510] == outs[10]
    assert outs[511] == [0, 0, 0, 0, 1, 0, 10000, 0, 0, 1, 0, 10000]  # stopped, braking


@needs_cc
def test_packet_filter_tb6612_mapping(build: Path) -> None:
    out = _filter(build, [f"0 {_wheels(2500, -250).hex()}", f"10 {_wheels(0, 0).hex()}"],
                  "-d", "tb6612", "-s", "2000", "-c", "-r")
    outs = _outputs(out)
    assert outs[0] == [2500, -250, 1, 10000, 1, 0, 10000, 1, 1250, 1, 0, 1250]  # clamped; right inverted
    assert outs[10] == [0, 0, 0, 0, 0, 0, 10000, 0, 0, 0, 0, 10000]  # coast: IN1 = IN2 = L, PWM = H


def test_status_example_bytes_match_protocol_md() -> None:
    doc = (HOST.parent / "PROTOCOL.md").read_text()
    examples = {
        "A": STATUS.pack(2, 0x81, 1234, 1230, 61234, 0, 3870, 100, -50, 0xFFFF, 0x10),
        "B": STATUS.pack(2, 0x81, 1240, 1236, 62034, 0, 3862, 0, 0, 0xFFFF, 0x11),
        "C": STATUS.pack(2, 0x81, 5000, 4990, 120500, 2, 3650, 0, 0, 8, 0x1C),
    }
    for name, payload in examples.items():
        assert f"`{bytes((DOWN,)).hex()} {payload.hex(' ')}`" in doc, name
    assert f"`{_wheels(100, -50).hex(' ')}`" in doc and f"`{_request(1234).hex(' ')}`" in doc


@needs_cc
def test_the_gateways_codec_and_the_c_app_understand_each_other(build: Path) -> None:
    """Packets encoded by the gateway's codec (`common.crazyflie.crtp`, the bytes it sends) decoded
    by the compiled C app, and the C app's STATUS replies decoded by the codec."""
    speeds = [(0.1, -0.05), (0.2, 0.2), (-0.0125, 0.0), (40.0, -40.0)]  # m/s; the last clamps to int16 mm/s
    lines = ["0 set vbat 3912", "0 set age 7", f"0 set flags {FLAG_ARMED:#x}"]
    lines += [f"{10 * (i + 1)} {crtp.encode_wheels(left, right).hex()}" for i, (left, right) in enumerate(speeds)]
    lines.append(f"100 {crtp.encode_status_request(4321).hex()}")
    out = _filter(build, lines, "-s", "40000")
    taken = [(int(rest[0]), int(rest[1])) for _t, kind, *rest in out if kind == "wheels"]
    assert taken == [(100, -50), (200, 200), (-12, 0), (32767, -32768)]
    replies = [bytes.fromhex(rest[0]) for _t, kind, *rest in out if kind == "reply"]
    assert len(replies) == 1
    status = crtp.decode_downlink(replies[0])
    assert status == crtp.Status(echo_seq=4321, received=5, uptime_ms=100, rejected=0, vbat_mv=3912,
                                 wheel_left_mm_s=32767, wheel_right_mm_s=-32768, setpoint_age_ms=7, flags=FLAG_ARMED)
