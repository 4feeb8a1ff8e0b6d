"""core.studies.tracking._study_cli: the command line and JSON set-up the studies share (the tissue
studies temporal_tissue, tissue_regressor, background_fit, tissue_stage; grid_correction, joint_bound,
hard_bound_check, tissue_bound, tibia_cost, spread_screen, tissue_tibia): their options, what ``main``
hands their ``run``, the checkpoints and the JSON at the end (the runs replaced: nothing rendered)."""

from __future__ import annotations

import importlib
import json
import re

import pytest

from core.studies.tracking import _study_cli as cli

#: each study's options as its --help lists them, in order
OPTIONS = {
    "temporal_tissue": ["--pixels", "--voxel", "--n-frames", "--frames", "--seeds", "--sets", "--variants",
                        "--bones", "--pose-error", "--residual-gain-hp", "--machine-name", "--table",
                        "--out"],
    "tissue_regressor": ["--pixels", "--voxel", "--n-frames", "--frames", "--seeds", "--sets", "--methods",
                         "--tissues", "--modes", "--pose-error", "--machine-name", "--out"],
    "background_fit": ["--pixels", "--voxel", "--n-frames", "--frames", "--seeds", "--sets", "--methods",
                       "--bones", "--components-frames", "--component-methods", "--machine-name", "--out"],
    "tissue_stage": ["--device", "--frames", "--pixels", "--voxel", "--workers", "--highpass", "--cases",
                     "--tissue", "--coarse-mm", "--no-tissue-psf", "--each", "--again", "--variants",
                     "--no-tracker", "--no-glare", "--correction", "--warm-frames", "--machine-name",
                     "--probe", "--probe-frames", "--probe-bones", "--probe-modes", "--probe-kinds", "--out"],
    # the bound and correction studies, their options as before they took this module's parser and ending
    "grid_correction": ["--pixels", "--grids", "--seed", "--machine-name", "--out"],
    "joint_bound": ["--quick", "--device", "--trial", "--pixels", "--spacing", "--frames", "--every",
                    "--stored", "--seed", "--machine-name", "--out"],
    "hard_bound_check": ["--pixels", "--voxel", "--frames", "--frame", "--seed", "--bone", "--draws",
                         "--tracker-draws", "--noise-draws", "--far-draws", "--no-response", "--bound-ratio",
                         "--reference", "--device", "--cache", "--machine-name", "--out"],
    "tissue_bound": ["--seed", "--pixels", "--voxel", "--every", "--frames", "--stored", "--keep",
                     "--grow-check", "--device", "--machine-name", "--out"],
    "tibia_cost": ["--pixels", "--voxel", "--frames", "--variants", "--costs", "--cost-variants", "--noises",
                   "--band-px", "--correction", "--start-deg", "--draws", "--device", "--machine-name",
                   "--acceptance", "--seed", "--quick", "--workers", "--speed", "--out"],
    "spread_screen": ["--pixels", "--voxel", "--frames", "--bones", "--draws", "--candidates", "--device",
                      "--machine-name", "--out"],
    "tissue_tibia": ["--bias", "--device", "--frames", "--pixels", "--voxel", "--bones", "--kinds",
                     "--highpass", "--workers", "--cases", "--labels", "--machine-name", "--out"],
}


def _study(name: str):
    return importlib.import_module(f"core.studies.tracking.{name}")


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_each_study_lists_its_options(name, capsys):
    with pytest.raises(SystemExit) as stop:
        _study(name).main(["--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: python -m core.studies.tracking.{name} ")
    assert re.findall(r"^  (--[a-z-]+)", text, flags=re.M) == OPTIONS[name]


def _stubbed(monkeypatch, mod, *fns):
    """Replace ``mod``'s run functions: each records what main handed it and checkpoints once."""
    seen = {}

    def stub(fn):
        def run(*, checkpoint=None, **kw):
            seen[fn] = kw
            res = {"study": mod.__name__, "results": {}}
            checkpoint(res)
            return res
        return run

    for fn in fns:
        monkeypatch.setattr(mod, fn, stub(fn))
    return seen


def test_main_hands_run_the_lists_and_writes_the_json(monkeypatch, tmp_path, capsys):
    mod = _study("temporal_tissue")
    seen = _stubbed(monkeypatch, mod, "run")
    out = tmp_path / "r.json"
    assert mod.main(["--frames", "4,,8", "--bones", "1,2", "--sets", "grid", "--machine-name", "one CPU",
                     "--table", "--out", str(out)]) == 0
    kw = seen["run"]
    assert kw["frames"] == [4, 8] and kw["bones"] == [1, 2] and kw["sets"] == ["grid"]
    assert kw["variants"] == ["hp4+r", "a4:hp0+r", "a4:hp2+r", "a4:hp4+r"] and kw["residual_gain_hp"] is None
    text = capsys.readouterr().out
    assert json.loads(text) == json.loads(out.read_text()) == {
        "study": "core.studies.tracking.temporal_tissue", "results": {}, "machine_name": "one CPU"}
    assert out.read_text() == text  # indented by two at the end (by one in the checkpoints)
    mod = _study("background_fit")
    seen = _stubbed(monkeypatch, mod, "run")
    assert mod.main(["--components-frames", "2,4"]) == 0
    kw = seen["run"]
    assert kw["bones"] is None and kw["components_frames"] == [2, 4] and kw["methods"] == list(mod.METHODS)
    assert "machine_name" not in json.loads(capsys.readouterr().out)
    assert mod.main(["--machine-name", "this 2-core x86_64 machine"]) == 0  # as the other studies
    assert json.loads(capsys.readouterr().out)["machine_name"] == "this 2-core x86_64 machine"


def test_tissue_stage_main_runs_the_probe_or_the_study(monkeypatch, capsys):
    mod = _study("tissue_stage")
    seen = _stubbed(monkeypatch, mod, "run", "probe")
    assert mod.main(["--probe", "--probe-bones", "1", "--highpass", "1,2",
                     "--probe-modes", "plain,robust"]) == 0
    kw = seen.pop("probe")
    assert kw["bones"] == [1] and kw["highpass"] == [1.0, 2.0] and kw["modes"] == ["plain", "robust"]
    assert kw["device"] == "cpu" and kw["n_frames"] == 100 and not seen
    assert "machine_name" not in json.loads(capsys.readouterr().out)
    assert mod.main(["--cases", "three", "--variants", "each,again", "--machine-name", "one H100"]) == 0
    kw = seen["run"]
    assert kw["cases"] == ["three"] and kw["variants"] == ["each", "again"] and kw["highpass"] == [4.0, 2.0]
    assert kw["device"] is None and kw["tracker"] and kw["glare"]
    assert json.loads(capsys.readouterr().out)["machine_name"] == "one H100"


def test_lists_checkpoint_header_and_frame_done(tmp_path, capsys):
    assert cli.names("a,,b,") == ["a", "b"] and cli.ints("") == [] and cli.ints("3,1") == [3, 1]
    assert cli.floats("4,2.5") == [4.0, 2.5]
    p = cli.parser("core.studies.tracking.x", "First line.\n\nMore.")
    cli.add_scene(p, frames="0,2", sets="true")
    cli.add_output(p, table=True)
    a = p.parse_args(["--machine-name", "m", "--out", str(tmp_path / "c.json")])
    assert (p.description, a.pixels, a.voxel, a.n_frames, a.frames, a.seeds, a.sets, a.table) == (
        "First line.", 256, 1.0, 20, "0,2", 2, "true", False)
    out = cli.header("core.studies.tracking.x", pixels=a.pixels)
    assert list(out) == ["study", "machine", "pixels"]
    cli.frame_done(out, 2, 0.0, cli.checkpoint(a), [0, 2])
    assert capsys.readouterr().out.startswith("frame 2 done ")
    saved = json.loads((tmp_path / "c.json").read_text())
    assert saved["frames_done"] == [0, 2] and saved["machine_name"] == "m" and saved["total_s"] > 0
    cli.frame_done(out, 3, 0.0, None)  # a frame not counted: frames_done as it was, nothing written
    assert out["frames_done"] == [0, 2] and json.loads((tmp_path / "c.json").read_text()) == saved


def _recorded(monkeypatch, mod, *fns):
    """Replace ``mod``'s ``fns``: each records its arguments (and checkpoints where handed one)."""
    seen = {}

    def stub(fn):
        def run(*args, **kw):
            seen[fn] = (args, kw)
            res = {"study": mod.__name__, "results": {}}
            if kw.get("checkpoint") is not None:
                kw["checkpoint"](res)
            return res
        return run

    for fn in fns:
        monkeypatch.setattr(mod, fn, stub(fn))
    return seen


@pytest.mark.parametrize(("name", "argv", "fn", "expected"), [
    ("grid_correction", ["--grids", "1,,3"], "run", {"pixels": 1024, "n_grids": [1, 3], "seed": 0}),
    ("joint_bound", ["--quick", "--seed", "3"], "run",
     {"quick": True, "device": None, "every": 10, "stored": None, "pixels": None, "seed": 3}),
    ("joint_bound", ["--trial", "hard", "--frames", "2"], "run_hard",
     {"pixels": 192, "spacing": 1.0, "n_frames": 2, "every": 1, "device": None, "seed": 0}),
    ("hard_bound_check", ["--bound-ratio", "1,3"], "bound_ratio",
     {"pixels": 192, "spacing": 1.0, "n_frames": 4, "seed": 0, "device": "cpu", "cache": None,
      "frames": [1, 3], "reference": None}),
    ("tissue_bound", ["--frames", "0,50", "--stored", ""], "run",
     {"seed": 0, "pixels": 256, "voxel_mm": 1.0, "every": 10, "frames": [0, 50], "stored": None,
      "grow_check": False, "keep": 0.5, "device": None}),
    ("tissue_bound", [], "run", {"frames": None, "stored": "default"}),
    ("tibia_cost", ["--speed", "--device", "auto"], "speed", {"workers": 0, "device": None}),
    ("tibia_cost", ["--acceptance", "band", "--quick"], "acceptance_with",
     {"seed": 0, "quick": True, "workers": 0, "device": "cpu"}),
    ("tibia_cost", ["--frames", "0,20", "--noises", "free"], "run",
     {"frames": [0, 20], "noises": ("free",), "device": "cpu", "variants": ("trial", "norim", "fill", "band",
                                                                             "notissue", "alone", "exact")}),
    ("spread_screen", ["--frames", "0,10", "--candidates", "a,,b"], "screen",
     {"pixels": 512, "voxel": 0.5, "frames": [0, 10], "bones": [0, 1, 2], "draws": 30,
      "candidates": ["a", "b"], "device": "cpu"}),
    ("tissue_tibia", ["--bias", "--kinds", "exact"], "bias",
     {"pixels": 256, "voxel": 1.0, "frames": list(range(0, 100, 10)), "bones": [0, 1, 2], "kinds": ["exact"],
      "highpass": 8.0, "device": "cpu"}),
    ("tissue_tibia", ["--frames", "20"], "run",
     {"device": None, "frames": 20, "pixels": 1024, "voxel": 0.5, "workers": 0, "cases": ["three", "tibia"],
      "labels": None}),
])
def test_the_bound_studies_main_hands_run_its_choices_and_ends_as_the_others(
        monkeypatch, tmp_path, capsys, name, argv, fn, expected):
    """Each converted main: the same arguments handed to its run as before, its JSON on stdout and to
    ``--out`` with ``machine_name``, as :func:`cli.finish` ends the tissue studies."""
    mod = _study(name)
    fns = {"joint_bound": ["run", "run_hard"], "hard_bound_check": ["run", "bound_ratio"],
           "tibia_cost": ["run", "speed", "acceptance_with"], "spread_screen": ["screen"],
           "tissue_tibia": ["run", "bias"]}
    seen = _recorded(monkeypatch, mod, *fns.get(name, ["run"]))
    out = tmp_path / "r.json"
    assert mod.main([*argv, "--machine-name", "one CPU", "--out", str(out)]) == 0
    (only,) = seen
    assert only == fn
    kw = seen[fn][1]
    assert {k: kw[k] for k in expected} == expected
    text = capsys.readouterr().out
    assert json.loads(text) == json.loads(out.read_text()) == {
        "study": mod.__name__, "results": {}, "machine_name": "one CPU"}


def test_write_stamped(tmp_path):
    """The stored-run studies' JSON: the stamp (study, command, commit, machine, CPU time), then the
    results."""
    import json

    from core.studies.tracking._study_cli import write_stamped

    out = tmp_path / "r.json"
    write_stamped(out, "core.studies.tracking.trajectory_pairs", ["--no-tune"], "m", {"x": 1})
    got = json.loads(out.read_text())
    assert list(got)[:5] == ["study", "command", "commit", "machine", "cpu_s"]
    assert got["study"] == "core.studies.tracking.trajectory_pairs"
    assert got["machine"] == "m" and got["x"] == 1
    assert got["command"] == "python -m core.studies.tracking.trajectory_pairs --no-tune"
    assert out.read_text().endswith("}\n") and '\n "x": 1' in out.read_text()
