"""`python -m tests.check_handlers` (the reproducible "each handling disabled, its test fails" table of
docs/reliability.md) stays runnable: every disabling change still finds its target text exactly once
and leaves valid Python, every test it names exists, and a copy of the tree on PYTHONPATH is what
the venv imports (not this checkout, which the venv has installed in editable mode)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from tests.check_handlers import HANDLINGS, REPO, Edit, TargetMissing, apply, check_targets


def test_every_disabling_change_finds_its_target_once_and_every_test_exists() -> None:
    assert check_targets(REPO) == []


def test_every_disabled_file_is_still_python() -> None:
    for h in HANDLINGS:
        texts: dict[str, str] = defaultdict(str)
        for e in h.edits:
            text = texts[e.path] or (REPO / e.path).read_text()
            assert text.count(e.old) == 1 and e.old != e.new, (h.name, e.old)
            texts[e.path] = text.replace(e.old, e.new)
        for path, text in texts.items():
            compile(text, path, "exec")  # raises on a change that breaks the syntax


def test_a_missing_target_stops_the_script_naming_it(tmp_path: Path) -> None:
    (tmp_path / "m.py").write_text("x = 1\nx = 1\n")
    with pytest.raises(TargetMissing, match="occurs 2 times"):
        apply(Edit("m.py", "x = 1\n", "x = 2\n"), tmp_path)
    with pytest.raises(TargetMissing, match="occurs 0 times"):
        apply(Edit("m.py", "y = 1\n", "y = 2\n"), tmp_path)
    apply(Edit("m.py", "x = 1\nx", "x = 2\nx"), tmp_path)
    assert (tmp_path / "m.py").read_text() == "x = 2\nx = 1\n"


def test_the_copy_on_pythonpath_is_what_the_venv_imports(tmp_path: Path) -> None:
    (tmp_path / "services").mkdir()
    (tmp_path / "services" / "__init__.py").write_text("")
    out = subprocess.run([sys.executable, "-c", "import services; print(services.__file__)"], cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(tmp_path)}, capture_output=True, text=True, check=True)
    assert Path(out.stdout.strip()).parent.parent == tmp_path


def test_the_script_is_not_collected_by_pytest() -> None:
    assert not Path(sys.modules["tests.check_handlers"].__file__).name.startswith("test_")
