"""Which executor owns which vehicle: rendezvous (highest-random-weight) hashing over the live
executors. Every executor and every gateway computes the same answer from the same set of
liveliness tokens, so no coordination message is needed; when an executor dies only its vehicles
move, spread over the others (Thaler & Ravishankar 1998)."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable


def _weight(vid: str, executor: str) -> int:
    digest = hashlib.blake2b(f"{executor}\x00{vid}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def owner_of(vid: str, executors: Iterable[str]) -> str | None:
    """The executor that owns `vid`, or None when no executor is alive."""
    return max(executors, key=lambda e: (_weight(vid, e), e), default=None)


def assignment(vids: Iterable[str], executors: Iterable[str]) -> dict[str, str | None]:
    live = sorted(set(executors))
    return {vid: owner_of(vid, live) for vid in vids}
