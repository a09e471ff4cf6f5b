"""The log subsystem, CRTP port 5 (crazyflie-firmware `src/modules/src/log.c`).

Channel 0 is the table of contents (`toc.py`); channel 1 controls log blocks and always answers
`[command, block id, errno]` (`logControlProcess()`); channel 2 carries the data of running blocks,
`[block id, 24-bit ms timestamp, values...]` (`logRunBlock()`). Limits: 16 blocks, 128 variables in
all, 26 bytes of values per block. A variable is fetched as the type the block asks for, converted
from its own (a float fetched as an integer is truncated toward zero and its low bytes kept). START
takes its period in 10 ms units (0: one packet); START_V2 in ms. When a block is due while the radio
link has been silent for a second (`radiolinkIsConnected()`), the firmware resets every block.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from services.sim.crazyflie.firmware.toc import Toc, TocEntry

PORT = 5
CH_TOC, CH_CONTROL, CH_DATA = 0, 1, 2
CMD_DELETE, CMD_START, CMD_STOP, CMD_RESET, CMD_CREATE_V2, CMD_APPEND_V2, CMD_START_V2 = 2, 3, 4, 5, 6, 7, 8
ENOENT, E2BIG, ENOEXEC, ENOMEM, EEXIST = 2, 7, 8, 12, 17
MAX_BLOCKS = 16
MAX_OPS = 128
MAX_BLOCK_BYTES = 26

# log.h types: code -> (struct format, is float)
TYPES: dict[int, tuple[str, bool]] = {1: ("<B", False), 2: ("<H", False), 3: ("<I", False), 4: ("<b", False),
                                     5: ("<h", False), 6: ("<i", False), 7: ("<f", True), 8: ("<e", True)}
UINT8, UINT16, UINT32, INT8, INT16, INT32, FLOAT, FP16 = 1, 2, 3, 4, 5, 6, 7, 8


@dataclass(frozen=True, slots=True)
class LogVar:
    group: str
    name: str
    type_code: int
    read: Callable[[], float]


def pack_value(value: float, type_code: int) -> bytes:
    """`value` as the firmware sends a variable fetched as `type_code`."""
    fmt, is_float = TYPES[type_code]
    if is_float:
        return struct.pack(fmt, float(value))
    size = struct.calcsize(fmt)
    as_int = math.trunc(value) if math.isfinite(value) else 0
    raw = as_int & ((1 << (8 * size)) - 1)  # the low bytes, as the C conversion keeps them
    return raw.to_bytes(size, "little")


@dataclass
class _Block:
    ops: list[tuple[int, int]] = field(default_factory=list)  # (variable id, fetch type)
    period_ms: float = 0.0
    next_ms: float = 0.0
    running: bool = False

    def size(self) -> int:
        return sum(struct.calcsize(TYPES[t][0]) for _, t in self.ops)


class LogService:
    """Log blocks over `variables`; times are ms since boot."""

    def __init__(self, variables: list[LogVar]) -> None:
        self.variables = variables
        self.toc = Toc([TocEntry(v.group, v.name, v.type_code) for v in variables],
                       info_tail=bytes((MAX_BLOCKS, MAX_OPS)))
        self.blocks: dict[int, _Block] = {}

    def reset(self) -> None:
        self.blocks.clear()

    def _ops_used(self) -> int:
        return sum(len(b.ops) for b in self.blocks.values())

    def control(self, payload: bytes, now_ms: float) -> bytes:
        """The reply to a channel-1 command."""
        if not payload:
            return bytes((0, 0, ENOEXEC))
        cmd = payload[0]
        bid = payload[1] if len(payload) > 1 else 0
        return bytes((cmd, bid, self._run(cmd, bid, payload, now_ms)))

    def _run(self, cmd: int, bid: int, payload: bytes, now_ms: float) -> int:
        if cmd == CMD_RESET:
            self.reset()
            return 0
        if cmd == CMD_CREATE_V2:
            if bid in self.blocks:
                return EEXIST
            if len(self.blocks) >= MAX_BLOCKS:
                return ENOMEM
            self.blocks[bid] = _Block()
            return self._append(self.blocks[bid], payload[2:])
        block = self.blocks.get(bid)
        if block is None:
            return ENOENT if cmd in (CMD_APPEND_V2, CMD_DELETE, CMD_START, CMD_STOP, CMD_START_V2) else ENOEXEC
        if cmd == CMD_APPEND_V2:
            return self._append(block, payload[2:])
        if cmd == CMD_DELETE:
            del self.blocks[bid]
        elif cmd == CMD_START:
            self._start(block, 10.0 * (payload[2] if len(payload) > 2 else 0), now_ms)
        elif cmd == CMD_START_V2:
            period = struct.unpack("<H", payload[2:4])[0] if len(payload) >= 4 else 0
            self._start(block, float(period), now_ms)
        elif cmd == CMD_STOP:
            block.running = False
        else:
            return ENOEXEC
        return 0

    def _append(self, block: _Block, ops: bytes) -> int:
        """Add `(type, id_lo, id_hi)` triples; ops added before an error stay (as in the firmware)."""
        for i in range(0, len(ops) - len(ops) % 3, 3):
            fetch, vid = ops[i] & 0x0F, ops[i + 1] | ops[i + 2] << 8
            if vid >= len(self.variables) or fetch not in TYPES:
                return ENOENT
            if block.size() + struct.calcsize(TYPES[fetch][0]) > MAX_BLOCK_BYTES:
                return E2BIG
            if self._ops_used() >= MAX_OPS:
                return ENOMEM
            block.ops.append((vid, fetch))
        return 0

    @staticmethod
    def _start(block: _Block, period_ms: float, now_ms: float) -> None:
        block.period_ms = period_ms
        block.next_ms = now_ms + period_ms
        block.running = True

    def due(self, now_ms: float, link_active: bool) -> list[bytes]:
        """Data payloads (channel 2) of the blocks due by `now_ms`; every block is reset instead
        when one is due with the link silent."""
        out = []
        for bid, block in list(self.blocks.items()):
            if not block.running or now_ms < block.next_ms:
                continue
            if not link_active:
                self.reset()
                return []
            ts = int(now_ms) & 0xFFFFFF
            values = b"".join(pack_value(self.variables[v].read(), t) for v, t in block.ops)
            out.append(bytes((bid, ts & 0xFF, ts >> 8 & 0xFF, ts >> 16)) + values)
            if block.period_ms > 0:
                block.next_ms = max(block.next_ms + block.period_ms, now_ms)
            else:
                block.running = False
        return out
