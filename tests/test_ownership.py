"""Rendezvous ownership: deterministic, balanced, and minimal movement when an executor dies."""

from __future__ import annotations

from collections import Counter

from common.domain.ownership import assignment, owner_of

VIDS = [f"cf{i:03d}" for i in range(400)]


def test_same_answer_whatever_the_order_of_executors() -> None:
    assert assignment(VIDS, ["a", "b", "c"]) == assignment(VIDS, ["c", "a", "b"])


def test_balanced_over_executors() -> None:
    counts = Counter(assignment(VIDS, ["e1", "e2", "e3", "e4"]).values())
    assert set(counts) == {"e1", "e2", "e3", "e4"}
    assert min(counts.values()) > 400 / 4 * 0.7


def test_only_the_dead_executors_vehicles_move() -> None:
    before = assignment(VIDS, ["e1", "e2", "e3"])
    after = assignment(VIDS, ["e1", "e3"])
    moved = {v for v in VIDS if before[v] != after[v]}
    assert moved == {v for v in VIDS if before[v] == "e2"}
    assert {after[v] for v in moved} == {"e1", "e3"}


def test_no_executor_no_owner() -> None:
    assert owner_of("cf1", []) is None
