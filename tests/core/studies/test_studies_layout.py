"""The evaluation package: its entry points run at their paths, and it finds the sample data."""

from __future__ import annotations

import importlib
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import core.studies
from core.studies import sample_data_dir

ROOT = Path(__file__).resolve().parents[3]


def _study_modules() -> list[str]:
    return [m.name for m in pkgutil.walk_packages(core.studies.__path__, "core.studies.")
            if not m.ispkg]


def test_every_entry_point_names_its_own_path():
    mains = 0
    for name in _study_modules():
        source = Path(importlib.import_module(name).__file__).read_text(encoding="utf-8")
        if "def main(" not in source:
            continue
        mains += 1
        assert 'if __name__ == "__main__":' in source, f"{name}: main() without a __main__ guard"
        for prog in re.findall(r'prog="python -m ([\w.]+)"', source):
            assert prog == name, f"{name}: its --help names {prog!r}"
    assert mains >= 14, f"expected the 14 study and benchmark entry points, found {mains}"


def test_python_m_runs_a_moved_entry_point():
    done = subprocess.run([sys.executable, "-m", "core.studies.io.benchmark", "--help"],
                          capture_output=True, text=True, encoding="utf-8", cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "python -m core.studies.io.benchmark" in done.stdout


def test_sample_data_dir_is_next_to_the_repository_or_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("TALUS_SAMPLE_DATA", raising=False)
    assert sample_data_dir() == ROOT.parent / "shared" / "data"
    monkeypatch.setenv("TALUS_SAMPLE_DATA", str(tmp_path))
    assert sample_data_dir() == tmp_path
