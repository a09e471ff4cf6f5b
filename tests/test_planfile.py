"""The plan file names its format (DESIGN.md, "Plan file"): written always, checked on reading."""

from __future__ import annotations

import json

import pytest

from common.domain.planfile import (
    PLAN_FORMAT,
    PlanFileError,
    Task,
    decode_plan,
    encode_plan,
    read_plan,
    write_plan,
)
from common.errors import InputError
from services.planner.maps.loading import problem_from_request
from services.planner.registry import run_planner


@pytest.fixture(scope="module")
def plan():
    tasks = {"cf1": Task(start="WP1", goal="WP6")}
    plan, result = run_planner(problem_from_request("town", tasks, "sipp"), "sipp", 0.5, 10.0, 0)
    assert plan is not None, result.error
    return plan


def test_a_written_plan_file_names_its_format_first(tmp_path, plan) -> None:
    path = tmp_path / "plan.json"
    write_plan(plan, path)
    doc = json.loads(path.read_text())
    assert doc["format"] == PLAN_FORMAT == "fleet-plan/1"
    assert next(iter(doc)) == "format"
    assert read_plan(path) == plan


@pytest.mark.parametrize("value", ["fleet-plan/2", "", 1, None])
def test_reading_a_wrong_format_names_the_field(tmp_path, plan, value) -> None:
    path = tmp_path / "plan.json"
    write_plan(plan, path)
    doc = json.loads(path.read_text())
    doc["format"] = value
    path.write_text(json.dumps(doc))
    with pytest.raises(PlanFileError) as err:
        read_plan(path)
    assert isinstance(err.value, InputError)
    assert err.value.field == "format"
    assert str(err.value).startswith(f"{path}: format: ")
    assert repr(value) in str(err.value) and PLAN_FORMAT in str(err.value)


def test_reading_a_file_without_format_names_the_field(tmp_path, plan) -> None:
    path = tmp_path / "plan.json"
    write_plan(plan, path)
    doc = json.loads(path.read_text())
    del doc["format"]
    path.write_text(json.dumps(doc))
    with pytest.raises(PlanFileError, match=r"format: missing") as err:
        read_plan(path)
    assert err.value.field == "format"


def test_other_decoding_errors_name_their_field(plan) -> None:
    doc = json.loads(encode_plan(plan))
    doc["mu"] = "half"
    with pytest.raises(PlanFileError) as err:
        decode_plan(json.dumps(doc), "p.json")
    assert err.value.field == "mu" and str(err.value).startswith("p.json: mu: ")
    with pytest.raises(PlanFileError) as err:
        decode_plan(b"[]", "p.json")
    assert err.value.field == "" and str(err.value).startswith("p.json: ")

