"""The API's public surface is `services.api.__all__` and nothing else (issue 19): no other public
name in the module, no private type in a public signature, a docstring on every public member,
docs/api.md generated from those docstrings, and examples that use only the public module."""

from __future__ import annotations

import ast
import inspect
import re
from pathlib import Path

import services.api as api
from services.api._reference import reference

REPO = Path(__file__).resolve().parents[1]
TYPING = {"str", "int", "float", "bool", "None", "dict", "list", "tuple", "set", "Path", "Iterable", "Mapping",
          "Callable", "Iterator", "AsyncIterator", "Any", "Literal", "EventKind"}
PUBLIC_SURFACE = {
    "AsyncFleet", "Fleet", "Mission", "SyncMission", "VehicleInfo", "MissionEvent", "MissionResult", "VehicleOutcome",
    "Plan", "Task", "TeamTask", "TeamPlan", "VehiclePlan", "Telemetry", "FleetError", "ConnectError", "PlanningError",
    "MissionFailed", "VehicleError", "UnknownVehicle", "VehicleBusy", "CommandRefused",
}


def public_members(obj: type):
    for name, member in vars(obj).items():
        if not name.startswith("_") and (callable(member) or isinstance(member, (property, classmethod))):
            yield name, member.__func__ if isinstance(member, classmethod) else member


def test_the_public_surface_is_all_and_only_all() -> None:
    assert set(api.__all__) == PUBLIC_SURFACE, "a change of the public surface: update this test and docs/api.md"
    leaked = {n for n in dir(api) if not n.startswith("_")} - set(api.__all__)
    assert not leaked, f"public names outside __all__: {sorted(leaked)}"


def test_public_signatures_name_only_public_types_and_every_member_has_a_docstring() -> None:
    for name in api.__all__:
        obj = getattr(api, name)
        assert inspect.getdoc(obj), f"{name} has no docstring"
        if not obj.__module__.startswith("services.api"):
            continue
        for attr, fn in public_members(obj):
            assert fn.__doc__, f"{name}.{attr} has no docstring"
            if isinstance(fn, property):
                continue
            for annotation in inspect.get_annotations(fn).values():
                text = re.sub(r"'[^']*'|\"[^\"]*\"", "", str(annotation))  # literals are values, not types
                words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text))
                private = words - TYPING - set(api.__all__)
                assert not private, f"{name}.{attr} names non-public types {sorted(private)} in its signature"


def test_docs_api_md_is_generated_from_the_docstrings() -> None:
    assert (REPO / "docs" / "api.md").read_text() == reference(), \
        "docs/api.md is stale: python -m services.api._reference > docs/api.md"


def test_examples_use_only_the_public_module() -> None:
    examples = sorted((REPO / "examples").glob("*.py"))
    assert len(examples) >= 5
    for path in examples:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            for module in names:
                if module.split(".")[0] in ("services", "common", "tests", "bench"):
                    assert module == "services.api", f"{path.name} imports {module}: examples use services.api only"
