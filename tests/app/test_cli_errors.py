"""How ``talus`` fails: exit statuses, one-line messages, a locked study, a fast ``--help``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import EXIT_ERROR, EXIT_LOCKED, EXIT_USAGE, main
from app.commands import COMMANDS

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("warp", "scipy", "matplotlib", "PySide6", "numpy", "cv2", "vtk", "pyvista")


def _imports_after(code: str) -> list[str]:
    """Heavy modules in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    probe = (f"import sys\n{code}\n"
             f"print([m for m in {HEAVY!r} if m in sys.modules])\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, encoding="utf-8",
                          timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1].replace("'", '"'))


def test_help_lists_every_command_on_one_line(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")  # a plain terminal
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    start = lines.index("  COMMAND") + 1
    listed = lines[start:lines.index("", start)]
    assert [ln.split()[0] for ln in listed] == list(COMMANDS), "\n".join(listed)  # no wrapping
    assert all(len(ln.split(None, 1)) == 2 for ln in listed), "\n".join(listed)


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["demo", "--frames", "x"],
                                  ["track", "--help"], ["frobnicate"]])
def test_help_version_and_usage_errors_import_no_heavy_module(argv):
    code = ("from app.cli import main\n"
            "try:\n"
            f"    main({argv!r})\n"
            "except SystemExit:\n"
            "    pass\n")
    assert _imports_after(code) == []


def test_importing_core_io_leaves_out_warp_matplotlib_and_qt():
    loaded = _imports_after("import core.io, core.study")
    assert not {"warp", "matplotlib", "PySide6", "vtk", "pyvista"} & set(loaded)


def test_unknown_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["frobnicate"])
    assert exc.value.code == EXIT_USAGE
    assert "invalid choice: 'frobnicate'" in capsys.readouterr().err


@pytest.fixture
def study(tmp_path):
    from core.study import Study

    with Study.create(tmp_path / "gait study", name="gait"):
        pass
    return tmp_path / "gait study"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("demo")
    make_demo_study(out, n_frames=2, pixels=48, spacing=3.0, tissue_spacing=6.0, device="cpu",
                    calibration_session=False)
    return out


def test_a_locked_bone_is_one_paragraph_naming_bone_holder_and_time(demo, capsys):
    from core.study import Study

    with Study.open(demo, mode="w") as st:  # another writer tracks the talus of this trial
        st.lock_journal("walk", "talus")
        status = main(["track", str(demo), "--trial", "walk", "--bones", "talus", "--quiet"])
    err = capsys.readouterr().err
    assert status == EXIT_LOCKED
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert f"bone 'talus' of trial 'walk' in study {demo}" in err and "since" in err
    assert f"process {os.getpid()}" in err


def test_a_locked_bone_from_a_second_process(demo):
    from core.study import Study

    with Study.open(demo, mode="w") as st:
        st.lock_journal("walk", "talus")
        done = subprocess.run([sys.executable, "-m", "app.cli", "track", str(demo), "--trial",
                               "walk", "--bones", "talus", "--quiet"],
                              capture_output=True, encoding="utf-8", timeout=120, cwd=ROOT)
    assert done.returncode == EXIT_LOCKED, done.stderr
    assert "Traceback" not in done.stderr and str(demo) in done.stderr
    assert f"process {os.getpid()}" in done.stderr


def test_library_errors_are_one_line_naming_the_file(study, capsys):
    (study / "study.json").write_text("{ not json")
    assert main(["track", str(study), "--trial", "walk"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "study.json" in err
    missing = study.parent / "nowhere"
    assert main(["track", str(missing), "--trial", "walk"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert str(missing) in err and ".talus.lock" not in err


def test_debug_shows_the_traceback(study, monkeypatch):
    monkeypatch.delenv("TALUS_DEBUG", raising=False)
    (study / "study.json").write_text("{ not json")
    with pytest.raises(ValueError, match=r"study\.json"):
        main(["--debug", "track", str(study), "--trial", "walk"])
    monkeypatch.setenv("TALUS_DEBUG", "1")
    with pytest.raises(ValueError, match=r"study\.json"):
        main(["track", str(study), "--trial", "walk"])


def test_an_unexpected_error_is_one_line_with_a_hint(monkeypatch, capsys):
    import types

    def boom(argv):
        raise TypeError("bad thing")

    monkeypatch.delenv("TALUS_DEBUG", raising=False)
    monkeypatch.setitem(sys.modules, "core.studies.io.benchmark",
                        types.SimpleNamespace(main=boom))
    assert main(["bench", "io"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "TypeError: bad thing" in err and "--debug" in err and "Traceback" not in err


def test_study_repair_keeps_good_records_and_reports_the_rest(tmp_path, capsys):
    import numpy as np

    from core.study import Study
    from core.synthetic import make_demo_study

    out = tmp_path / "demo"
    make_demo_study(out, n_frames=3, pixels=64, spacing=4.0, tissue_spacing=8.0, device="cpu",
                    calibration_session=False)
    with Study.open(out, mode="w") as st:
        tr = st.trial("walk")
        for f in (1, 2):
            tr.record_pose("talus", f, tr.poses("talus")[0])
    journal = out / "results" / "walk" / "poses" / "talus.jsonl"
    lines = journal.read_bytes().splitlines(keepends=True)
    assert len(lines) == 3
    bad = bytearray(lines[1])
    bad[12] ^= 0x01  # one flipped byte in the middle record
    journal.write_bytes(lines[0] + bytes(bad) + lines[2])
    with Study.open(out) as st, pytest.raises(ValueError):
        st.trial("walk").poses("talus")
    assert main(["study", "repair", str(out), "--dry-run"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["dry_run"] and report["damaged"] == 1 and report["dropped_lines"] == 1
    assert journal.read_bytes() == lines[0] + bytes(bad) + lines[2]  # unchanged
    assert main(["study", "repair", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert not report["dry_run"] and report["damaged"] == 1 and report["dropped_lines"] == 1
    with Study.open(out) as st:
        poses = st.trial("walk").poses("talus")
    assert np.isfinite(poses[0]).all() and np.isfinite(poses[2]).all()
    assert not np.isfinite(poses[1]).all()  # the damaged record is not taken as a pose
