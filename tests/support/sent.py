"""A stand-in for an unstarted service's publishers, for tests that run its cycles directly."""

from __future__ import annotations

from typing import Any


class SentMessages:
    """Stands in for one publisher (`Publisher.put`) or a set keyed by mission or vehicle
    (`KeyedPublishers.put`): the messages put."""

    def __init__(self) -> None:
        self.msgs: list[Any] = []

    def put(self, *key_and_msg: object) -> None:
        self.msgs.append(key_and_msg[-1])
