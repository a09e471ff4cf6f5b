"""`make results` (bench/results.py): Table II from the planner's battery model, the report's pieces,
and (under `-m scale`) the whole pipeline in its --quick form."""

from __future__ import annotations

import pytest

from bench import results


def test_table2_from_the_model_matches_the_papers_flight_and_explains_driving() -> None:
    t = results.table2()
    car, wheels = t["rows"]["Flying Car"], t["rows"]["Wheels"]
    assert car["run_min"] == pytest.approx(5.0, abs=0.05) and car["distance_m"] == pytest.approx(90, abs=1)
    assert car["cot"] == pytest.approx(64.9, abs=0.1) and wheels["cot"] == pytest.approx(14.9, abs=0.1)
    assert wheels["run_min"] == pytest.approx(65.1, abs=0.1)  # the paper measured 42 min
    paper = t["paper_energy_j"]
    assert paper["Flying Car"] == pytest.approx(paper["Crazyflie"], rel=0.01)  # one battery's worth
    assert paper["Wheels"] / paper["Flying Car"] == pytest.approx(0.64, abs=0.01)  # the inconsistency
    text = results.section_table2(t)
    assert "pending" in text and "64 %" in text


def test_markdown_table() -> None:
    assert results.md_table(["a", "b"], [[1, "x"]]) == "| a | b |\n|---|---|\n| 1 | x |"


def test_fig6_section_says_reproduced() -> None:
    from bench import fig6

    text = results.section_fig6(fig6.run(log=lambda _s: None))
    assert "**reproduced" in text and "![Fig. 6](results/fig6.png)" in text


@pytest.mark.scale
def test_quick_pipeline_writes_the_report_and_figures(tmp_path) -> None:
    assert results.main(["--quick", "--docs", str(tmp_path), "--data", str(tmp_path / "data")]) == 0
    report = (tmp_path / "results.md").read_text()
    for heading in ("Fig. 6", "Fig. 7", "Table II", "934-node", "MovingAI", "Paper 002"):
        assert heading in report
    for png in ("fig6", "fig7", "scale_city", "collab_experiment"):
        assert (tmp_path / "results" / f"{png}.png").stat().st_size > 10_000
    assert "cores" in report and "commit" in report
