"""Interop in the command and the window: ``talus import`` of an XMALab project, File → Import
project… (Autoscoper .cfg or XMALab .xma → a new study, opened) and File → Export… (every pose
format of core.study.exports; the files read back equal)."""

from __future__ import annotations

import json

import numpy as np

from tests.core.study.test_import_xma import make


def test_cli_imports_an_xma_project(tmp_path, capsys):
    from app.cli import main

    p = make(tmp_path)
    assert main(["import", str(p), "--study", str(tmp_path / "st")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["trials"] == {"hop_1": 4} and summary["format"] == "xmalab-xma"
    assert summary["markers"] == {"hop_1": 2} and summary["calibrations"] == ["xmalab.v1"]
    assert main(["import", str(p), "--out", str(tmp_path / "st")]) == 1  # a study is there already
    assert "already holds a study" in capsys.readouterr().err
    assert main(["import", str(p), "--out", str(tmp_path / "s2"), "--tra", "x.tra"]) == 1
    assert "--tra: only for an Autoscoper .cfg" in capsys.readouterr().err
    assert not (tmp_path / "s2").exists()
    assert np.isfinite(summary["trials"]["hop_1"])
