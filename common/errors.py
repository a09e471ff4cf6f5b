"""Errors for bad input: each names the file, the field and the problem (the CLI exits 2 on them)."""

from __future__ import annotations


class InputError(Exception):
    """Bad user input (map, scenario, config, plan): `source: field: problem`."""

    def __init__(self, source: str, field: str, problem: str) -> None:
        self.source = source
        self.field = field
        self.problem = problem
        where = f"{source}: {field}" if field else source
        super().__init__(f"{where}: {problem}")
