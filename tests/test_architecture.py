"""The dependency rules of ../shared/DESIGN.md, enforced: import-linter's contracts (`.importlinter`)
hold on the tree, and each kind of violation they exist for breaks the suite."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"


def _lint(root: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run([str(LINT_IMPORTS), "--config", str(root / ".importlinter"), "--no-cache"], cwd=root,
                          env=env, capture_output=True, text=True, timeout=120)


def test_the_tree_keeps_every_import_contract() -> None:
    result = _lint(REPO)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "BROKEN" not in result.stdout


@pytest.mark.parametrize("module,line,contract", [
    ("services/radio_gateway/_violation.py", "from services.executor import trajectory", "no service imports another"),
    ("services/telemetry/_violation.py", "import services.sim.crazyflie.physics", "nothing real imports the simulator"),
    ("common/bus/_violation.py", "from services.planner import registry", "common never imports services"),
    ("common/domain/_violation.py", "from common.bus import keys", "common's parts in layers"),
])
def test_a_forbidden_import_breaks_its_contract(tmp_path: Path, module: str, line: str, contract: str) -> None:
    """The same contracts on a copy of the tree with one forbidden import added."""
    for part in ("common", "services", "tests", "bench"):
        shutil.copytree(REPO / part, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    shutil.copy(REPO / ".importlinter", tmp_path / ".importlinter")
    (tmp_path / module).write_text(f'"""A planted violation."""\n\n{line}\n')
    result = _lint(tmp_path)
    assert result.returncode != 0, result.stdout[-3000:]
    broken = " ".join(result.stdout.split("Broken contracts")[-1].split())  # the report wraps long names
    assert contract in broken and module[:-3].replace("/", ".") in broken, result.stdout[-3000:]
