"""The ``talus`` command line: parsing, JSON on stdout, errors, Ctrl-C cancellation.

The numerical commands are exercised with stand-ins for the core functions, so these tests stay
fast and need no display; the real ``core`` functions have their own tests.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import types
from pathlib import Path

import pytest

from app import __version__
from app.cli import EXIT_CANCELLED, main

ROOT = Path(__file__).resolve().parents[2]


def _talus_command() -> list[str]:
    script = Path(sys.executable).with_name("talus")
    return [str(script)] if script.exists() else [sys.executable, "-m", "app.cli"]


def _fake_module(monkeypatch, name: str, **attrs) -> None:
    monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(__name__=name, **attrs))


def test_version_console_script():
    done = subprocess.run(
        [*_talus_command(), "--version"], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"talus {__version__}"


def test_cli_works_without_qt():
    code = (
        "import sys\n"
        "for m in ('PySide6', 'pyvistaqt', 'pyvista', 'vtk'): sys.modules[m] = None\n"
        "from app.cli import main\n"
        "sys.exit(main(['bench', 'drr', '--help']))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert "--quick" in done.stdout


def test_bench_drr_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "drr", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for option in ("--device", "--out", "--quick", "{cpu,cuda,all}"):
        assert option in out


def test_track_and_module_benchmarks_take_their_options_without_a_separator(monkeypatch, capsys):
    seen = {}

    def fake_main(argv):
        seen["argv"] = list(argv)
        return 0

    with pytest.raises(SystemExit) as exc:  # talus track's own options, listed in full
        main(["track", "--help"])
    assert exc.value.code == 0 and "--max-uncertainty" in capsys.readouterr().out
    _fake_module(monkeypatch, "core.studies.tracking.benchmark", main=fake_main)
    assert main(["bench", "track", "--cases", "one", "--frames", "10"]) == 0
    assert seen["argv"] == ["--cases", "one", "--frames", "10"]
    assert main(["bench", "track", "--", "--help"]) == 0 and seen["argv"] == ["--help"]
    with pytest.raises(SystemExit) as exc:  # commands without a module still refuse strangers
        main(["demo", "--frobnicate"])
    assert exc.value.code == 2 and "--frobnicate" in capsys.readouterr().err


def test_bench_track_help_names_talus_bench_track(capsys):
    """Its usage said 'python -m core.studies.tracking.benchmark'; the module keeps its own name."""
    with pytest.raises(SystemExit) as exc:
        main(["bench", "track", "--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith("usage: talus bench track [-h]")
    from core.studies.tracking.benchmark import main as module_main

    with pytest.raises(SystemExit):
        module_main(["--help"])
    assert capsys.readouterr().out.startswith("usage: python -m core.studies.tracking.benchmark")


def test_no_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    assert "required" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["bench", "drr", "--device", "tpu"], "invalid choice: 'tpu'"),
        (["demo", "--frames", "0"], "--frames: expected a positive integer, got 0"),
        (["demo", "--seed", "x"], "--seed: expected an integer >= 0, got 'x'"),
    ],
)
def test_bad_arguments_are_named(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_missing_module_is_named(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "core.studies.render.benchmark", None)  # import fails
    assert main(["bench", "drr", "--device", "cpu"]) == 1
    err = capsys.readouterr().err
    assert "'talus bench drr' needs the module 'core.studies.render.benchmark'" in err
    assert "Traceback" not in err


def test_gui_rejects_missing_demo_folder(tmp_path, capsys):
    pytest.importorskip("PySide6")
    assert main(["gui", "--demo", str(tmp_path / "nowhere")]) == 1
    assert "--demo: expected a study folder" in capsys.readouterr().err


def test_gui_without_display_is_a_clear_error(monkeypatch, capsys):
    pytest.importorskip("PySide6")
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert main(["gui"]) == 1
    assert "'talus gui' needs a display: DISPLAY is not set" in capsys.readouterr().err


def test_bench_drr_prints_json_and_writes_file(monkeypatch, tmp_path, capsys):
    calls = []

    def run_drr_benchmark(*, devices, quick):
        calls.append((devices, quick))
        print("banner a library prints")  # must not end up in stdout's JSON
        return {"benchmark": "drr", "devices": {d: {"ms": 1.5} for d in devices}}

    _fake_module(monkeypatch, "core.studies.render.benchmark", run_drr_benchmark=run_drr_benchmark)
    out_file = tmp_path / "sub" / "drr.json"
    assert main(["bench", "drr", "--device", "cpu", "--quick", "--out", str(out_file)]) == 0
    assert calls == [(["cpu"], True)]
    captured = capsys.readouterr()
    expected = {"benchmark": "drr", "devices": {"cpu": {"ms": 1.5}}}
    assert json.loads(captured.out) == expected
    assert json.loads(out_file.read_text()) == expected
    assert "banner" in captured.err
    assert list(out_file.parent.iterdir()) == [out_file]  # no temporary file left behind


def test_demo_reports_progress_and_json(monkeypatch, tmp_path, capsys):
    def make_demo_study(out_dir, *, n_frames=10, pixels=512, seed=0, device=None, progress,
                        cancel):
        for i in range(n_frames):
            assert not cancel()
            progress(i + 1, n_frames)
        return {"out_dir": Path(out_dir), "frames": n_frames, "pixels": pixels, "seed": seed,
                "device": device}

    _fake_module(monkeypatch, "core.synthetic.demo", make_demo_study=make_demo_study)
    argv = ["demo", "--out", str(tmp_path), "--frames", "3", "--pixels", "64", "--seed", "7",
            "--no-gui"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {  # --device left out: the demo's default
        "out_dir": str(tmp_path), "frames": 3, "pixels": 64, "seed": 7, "device": None
    }
    lines = [ln for ln in captured.err.splitlines() if "frame" in ln]
    assert [ln.split(": ")[1].split(" (")[0] for ln in lines] == [
        "frame 1/3", "frame 2/3", "frame 3/3"
    ]


def test_ctrl_c_cancels_the_demo_cleanly(monkeypatch, tmp_path, capsys):
    seen = []

    def make_demo_study(out_dir, *, n_frames, progress, cancel):
        for i in range(n_frames):
            if cancel():
                seen.append(i)
                return {"status": "cancelled", "frames_written": i}
            progress(i + 1, n_frames)
            if i == 1:
                os.kill(os.getpid(), signal.SIGINT)  # the user presses Ctrl-C
        return {"cancelled": False}

    _fake_module(monkeypatch, "core.synthetic.demo", make_demo_study=make_demo_study)
    before = signal.getsignal(signal.SIGINT)
    assert main(["demo", "--out", str(tmp_path), "--frames", "10", "--no-gui"]) == EXIT_CANCELLED
    assert seen == [2]  # the job saw the request at its next check and stopped
    assert signal.getsignal(signal.SIGINT) is before  # handler restored
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {"status": "cancelled", "frames_written": 2}
    assert "cancelled" in captured.err


def test_sample_wrist_writes_preview_png(sample_data, tmp_path, capsys):
    folder = sample_data / "autoscoper_wrist"
    if not folder.is_dir():
        pytest.skip(reason=f"wrist sample not found at {folder}")
    out = tmp_path / "wrist.png"
    assert main(["sample", "wrist", "--data", str(folder), "--out", str(out), "--device", "cpu"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["views"] == 2 and min(result["drr_max"]) > 0.3
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sample_wrist_names_a_missing_folder(tmp_path, capsys):
    assert main(["sample", "wrist", "--data", str(tmp_path / "nope")]) != 0
    assert "--data" in capsys.readouterr().err


def test_demo_reuses_a_complete_study_with_the_same_options(monkeypatch, tmp_path, capsys):
    calls = []

    def make_demo_study(out_dir, *, progress, cancel, **options):
        calls.append(options)
        summary = {"format": "talus-synthetic-study", "status": "complete", "n_frames": 3,
                   "pixels": 64, "seed": 0, "calibration_session": "calibration_session"}
        (Path(out_dir) / "calibration_session").mkdir(exist_ok=True)
        (Path(out_dir) / "calibration_session" / "session.json").write_text("{}")
        (Path(out_dir) / "summary.json").write_text(json.dumps(summary))
        (Path(out_dir) / "study.json").write_text("{}")
        return summary

    _fake_module(monkeypatch, "core.synthetic.demo", make_demo_study=make_demo_study)
    argv = ["demo", "--out", str(tmp_path), "--frames", "3", "--pixels", "64", "--no-gui"]
    assert main(argv) == 0
    assert main(argv) == 0  # cached
    assert len(calls) == 1
    assert "using the demo study already in" in capsys.readouterr().err
    assert main([*argv, "--pixels", "32"]) == 0  # other options: rebuilt
    assert main([*argv, "--regenerate"]) == 0
    assert len(calls) == 3
    (tmp_path / "study.json").unlink()  # a demo folder without its study manifest: rebuilt
    assert main(argv) == 0
    assert len(calls) == 4
    (tmp_path / "calibration_session" / "session.json").unlink()  # session gone: rebuilt
    assert main(argv) == 0
    assert len(calls) == 5


@pytest.mark.parametrize("name", ["io", "imaging", "markers", "calibration"])
def test_bench_help_names_talus_bench(name, capsys):
    """Like 'talus bench track': each module's own name stays for 'python -m'."""
    import importlib

    with pytest.raises(SystemExit) as exc:
        main(["bench", name, "--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: talus bench {name} [-h]")
    module_main = importlib.import_module(f"core.studies.{name}.benchmark").main
    with pytest.raises(SystemExit):
        module_main(["--help"])
    assert capsys.readouterr().out.startswith(f"usage: python -m core.studies.{name}.benchmark")


def test_bench_metrics_takes_argv_and_prog(monkeypatch, capsys):
    """'talus bench metrics' hands its options to main(argv, prog=...), not through sys.argv;
    'python -m core.studies.similarity.benchmark' keeps its own name."""
    from core.studies.similarity import benchmark

    monkeypatch.setattr(sys, "argv", ["elsewhere", "--quick"])  # must not be read
    with pytest.raises(SystemExit) as exc:
        main(["bench", "metrics", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: talus bench metrics [-h]")
    assert "Measured (Warp" not in out  # the docstring's first line, not the whole of it
    with pytest.raises(SystemExit):
        benchmark.main(["--help"])
    assert capsys.readouterr().out.startswith("usage: python -m core.studies.similarity.benchmark")

    seen = {}
    monkeypatch.setattr(benchmark, "run_similarity_benchmark",
                        lambda **kw: seen.update(kw) or {"quick": kw["quick"]})
    assert main(["bench", "metrics", "--kind", "ncc", "--device", "cpu"]) == 0
    assert seen == {"devices": ["cpu"], "quick": False, "kinds": ("ncc",)}
    assert json.loads(capsys.readouterr().out) == {"quick": False}
