"""The parameter subsystem, CRTP port 2 (crazyflie-firmware `src/modules/src/param_logic.c`,
`param_task.c`, `src/modules/interface/param.h`).

Channels: 0 table of contents (`toc.py`), 1 READ `[id] -> [id, 0, value]`, 2 WRITE `[id, value]`
echoed unchanged as the acknowledgement (a read-only parameter gets no answer, an unknown one
`[id, ENOENT]`), 3 MISC: set by name, the extended type of persistent parameters (which cflib asks
for before it reports `connected`), default values and the persistent store. The type byte: bits 1-0
size (1, 2, 4, 8 bytes), bit 2 float, bit 3 unsigned, 0x10 extended (persistent), 0x20 core, 0x40
read-only. Values are kept as Python numbers and packed little-endian.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from services.sim.crazyflie.firmware.toc import Toc, TocEntry

PORT = 2
CH_TOC, CH_READ, CH_WRITE, CH_MISC = 0, 1, 2, 3
MISC_SETBYNAME, MISC_VALUE_UPDATED, MISC_GET_EXTENDED_TYPE = 0, 1, 2
MISC_PERSISTENT_STORE, MISC_PERSISTENT_GET_STATE, MISC_PERSISTENT_CLEAR = 3, 4, 5
MISC_GET_DEFAULT, MISC_GET_EXTENDED_TYPE_V2, MISC_GET_DEFAULT_V2 = 6, 7, 8
ENOENT, EINVAL, EACCES = 2, 22, 13

UINT8, UINT16, UINT32, INT8, INT16, INT32, FLOAT = 0x08, 0x09, 0x0A, 0x00, 0x01, 0x02, 0x06
EXTENDED, CORE, RONLY = 0x10, 0x20, 0x40
EXT_PERSISTENT = 1


def value_format(type_byte: int) -> str:
    size = type_byte & 0x03
    if type_byte & 0x04:
        return {1: "<e", 2: "<f", 3: "<d"}[size]
    return ("<" + "bhiq"[size]).upper() if type_byte & 0x08 else "<" + "bhiq"[size]


@dataclass
class Param:
    group: str
    name: str
    type_byte: int
    default: float
    on_set: Callable[[float], None] | None = None

    @property
    def read_only(self) -> bool:
        return bool(self.type_byte & RONLY)

    @property
    def persistent(self) -> bool:
        return bool(self.type_byte & EXTENDED)


class ParamService:
    """Parameters with their current values; `stored` (the persistent store) survives `reboot`."""

    def __init__(self, params: list[Param]) -> None:
        self.params = params
        self.toc = Toc([TocEntry(p.group, p.name, p.type_byte) for p in params])
        self.values: dict[str, float] = {}
        self.stored: dict[str, float] = {}
        self.reboot()

    def reboot(self) -> None:
        """Defaults, then what the persistent store holds (`paramLogicStorageInit()`)."""
        self.values = {f"{p.group}.{p.name}": p.default for p in self.params}
        self.values.update(self.stored)

    def get(self, name: str) -> float:
        return self.values[name]

    def set(self, name: str, value: float) -> None:
        """Set from firmware code (as `paramSetInt/Float`); runs the parameter's callback."""
        self.values[name] = value
        p = self.params[self.toc.ids[name]]
        if p.on_set is not None:
            p.on_set(value)

    def _param(self, payload: bytes, at: int = 0) -> tuple[int, Param | None]:
        if len(payload) < at + 2:
            return -1, None
        pid = payload[at] | payload[at + 1] << 8
        return pid, self.params[pid] if pid < len(self.params) else None

    def _pack(self, p: Param, value: float) -> bytes:
        fmt = value_format(p.type_byte)
        return struct.pack(fmt, float(value) if p.type_byte & 0x04 else int(value))

    def read(self, payload: bytes) -> bytes | None:
        pid, p = self._param(payload)
        if pid < 0:
            return None
        if p is None:
            return payload[:2] + bytes((ENOENT,))
        return payload[:2] + b"\0" + self._pack(p, self.values[f"{p.group}.{p.name}"])

    def write(self, payload: bytes) -> bytes | None:
        pid, p = self._param(payload)
        if pid < 0:
            return None
        if p is None:
            return payload[:2] + bytes((ENOENT,))
        if p.read_only:
            return None
        fmt = value_format(p.type_byte)
        size = struct.calcsize(fmt)
        if len(payload) < 2 + size:
            return None
        (value,) = struct.unpack(fmt, payload[2:2 + size])
        self.set(f"{p.group}.{p.name}", value)
        return payload

    def misc(self, payload: bytes) -> bytes | None:
        if not payload:
            return None
        cmd = payload[0]
        if cmd == MISC_SETBYNAME:
            return self._set_by_name(payload)
        pid, p = self._param(payload, 1)
        if pid < 0:
            return None
        head = payload[:3]
        if cmd == MISC_GET_EXTENDED_TYPE_V2:
            return head + (bytes((0, EXT_PERSISTENT)) if p is not None and p.persistent else bytes((ENOENT,)))
        if cmd == MISC_GET_EXTENDED_TYPE:
            return head + bytes((EXT_PERSISTENT if p is not None and p.persistent else ENOENT,))
        if cmd in (MISC_GET_DEFAULT_V2, MISC_GET_DEFAULT):
            if p is None or p.read_only:
                return head + bytes((ENOENT,))
            return head + (b"\0" if cmd == MISC_GET_DEFAULT_V2 else b"") + self._pack(p, p.default)
        if p is None or not p.persistent:
            return head + bytes((ENOENT,))
        name = f"{p.group}.{p.name}"
        if cmd == MISC_PERSISTENT_STORE:
            self.stored[name] = self.values[name]
            return head + b"\0"
        if cmd == MISC_PERSISTENT_CLEAR:
            self.stored.pop(name, None)
            return head + b"\0"
        if cmd == MISC_PERSISTENT_GET_STATE:
            state = bytes((1 if name in self.stored else 0,)) + self._pack(p, p.default)
            return head + state + (self._pack(p, self.stored[name]) if name in self.stored else b"")
        return None

    def _set_by_name(self, payload: bytes) -> bytes | None:
        parts = payload[1:].split(b"\0", 2)
        if len(parts) < 3 or not parts[2]:
            return None
        group, name, rest = parts[0].decode(errors="replace"), parts[1].decode(errors="replace"), parts[2]
        head = payload[:len(parts[0]) + len(parts[1]) + 3]
        full = f"{group}.{name}"
        if full not in self.toc.ids:
            return head + bytes((ENOENT,))
        p = self.params[self.toc.ids[full]]
        if p.read_only:
            return head + bytes((EACCES,))
        type_byte, raw = rest[0], rest[1:]
        if type_byte & 0x0F != p.type_byte & 0x0F:
            return head + bytes((EINVAL,))
        fmt = value_format(p.type_byte)
        (value,) = struct.unpack(fmt, raw[:struct.calcsize(fmt)])
        self.set(full, value)
        return head + b"\0"
