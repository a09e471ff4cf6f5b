"""Tables of contents of the log and parameter subsystems (crazyflie-firmware `src/modules/src/log.c`
`logTOCProcess()`, `param_logic.c` `paramTOCProcess()`; protocol version 2 only, as the firmware).

An entry is a group, a name and a type byte; its id is its position. GET_INFO_V2 answers the count
and a CRC that changes whenever the table does (cflib caches tables by CRC alone); GET_ITEM_V2
answers `[2, id_lo, id_hi, type, group, 0, name, 0]`, and an id past the end just `[2]`. The CRC is
computed as the firmware does (`logInit()` / `paramLogicInit()`): CRC-32 over every group start
(type 0x81, the group's name), variable (its type byte, its name) and group end (0x80,
"stop_<group>"), each chained through the previous value.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

TOC_CHANNEL = 0
CMD_TOC_ITEM_V2 = 2
CMD_TOC_INFO_V2 = 3
GROUP_START = 0x81
GROUP_STOP = 0x80
MAX_NAME_BYTES = 26
"""group + name + two NULs must fit a packet (the firmware asserts it)."""


@dataclass(frozen=True, slots=True)
class TocEntry:
    group: str
    name: str
    type_byte: int

    @property
    def full_name(self) -> str:
        return f"{self.group}.{self.name}"


def toc_crc(entries: list[TocEntry]) -> int:
    """The firmware's table CRC (module docstring)."""
    crc = 0
    group = None

    def add(type_byte: int, name: str) -> None:
        nonlocal crc
        crc = zlib.crc32(struct.pack("<I", crc) + bytes((type_byte,)) + name.encode())

    for e in entries:
        if e.group != group:
            if group is not None:
                add(GROUP_STOP, f"stop_{group}")
            group = e.group
            add(GROUP_START, group)
        add(e.type_byte, e.name)
    if group is not None:
        add(GROUP_STOP, f"stop_{group}")
    return crc


class Toc:
    """One subsystem's table; `info_tail` is what GET_INFO_V2 appends after count and CRC (the log's
    block and operation limits)."""

    def __init__(self, entries: list[TocEntry], info_tail: bytes = b"") -> None:
        for e in entries:
            if len(e.group) + len(e.name) + 2 > MAX_NAME_BYTES:
                raise ValueError(f"TOC name too long: {e.full_name}")
        self.entries = entries
        self.ids = {e.full_name: i for i, e in enumerate(entries)}
        self.crc = toc_crc(entries)
        self._info_tail = info_tail

    def answer(self, payload: bytes) -> bytes | None:
        """The reply payload to a TOC request (channel 0), or None (the firmware ignores v1 commands)."""
        if not payload:
            return None
        if payload[0] == CMD_TOC_INFO_V2:
            return bytes((CMD_TOC_INFO_V2,)) + struct.pack("<HI", len(self.entries), self.crc) + self._info_tail
        if payload[0] == CMD_TOC_ITEM_V2 and len(payload) >= 3:
            i = payload[1] | payload[2] << 8
            if i >= len(self.entries):
                return bytes((CMD_TOC_ITEM_V2,))
            e = self.entries[i]
            return (bytes((CMD_TOC_ITEM_V2, payload[1], payload[2], e.type_byte)) + e.group.encode() + b"\0"
                    + e.name.encode() + b"\0")
        return None
