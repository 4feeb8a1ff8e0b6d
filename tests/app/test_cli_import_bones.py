"""talus import --bones: names matched to the scan's bones (per-bone CTs by file name, label maps'
bone<label>) by name where they are those names, case aside; the others in the scan's order."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.cli import main as talus
from app.commands.import_folder import bones_by_name
from tests.app._helpers import lab_collection, small_demo

CTS = {"calcaneus": None, "talus": None}  # ct/calcaneus.mha, ct/talus.mha: scanned alphabetically


def test_names_of_the_files_take_their_files_in_any_order_and_case():
    assert bones_by_name(["talus", "calcaneus"], CTS) == {"calcaneus": None, "talus": None}
    assert list(bones_by_name(["Talus", "Calcaneus"], CTS)) == ["Calcaneus", "Talus"]


def test_a_name_of_a_file_keeps_it_when_the_other_name_is_new():
    """--bones talus,tibia gave the talus the calcaneus's CT (the names were not all the files')."""
    assert list(bones_by_name(["talus", "tibia"], CTS)) == ["tibia", "talus"]


def test_other_names_go_in_the_scans_order():
    assert list(bones_by_name(["a", "b"], CTS)) == ["a", "b"]
    labels = {"bone1": 1, "bone2": 2}
    assert bones_by_name(["bone2", "bone1"], labels) == {"bone1": 1, "bone2": 2}
    assert bones_by_name(["x", "bone1"], labels) == {"bone1": 1, "x": 2}
    assert bones_by_name(["x", "y"], labels) == {"x": 1, "y": 2}


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A collection folder: two frame folders, two MayaCam files, one CT per bone (48 px demo)."""
    demo = small_demo(tmp_path_factory.mktemp("demo") / "study")
    return lab_collection(demo, tmp_path_factory.mktemp("lab") / "lab")


def _files(study) -> dict:
    from core.study import Study

    with Study.open(study) as st:
        doc = st._doc
    return {b: Path(doc["volumes"][doc["bones"][b]["volume"]]["path"]).name for b in doc["bones"]}


def test_import_keeps_a_named_bones_file_beside_a_new_name(lab, tmp_path, capsys):
    assert talus(["import", str(lab), "--out", str(tmp_path / "s"), "--bones", "talus, tibia"]) == 0
    assert f"bone talus from {lab / 'ct' / 'talus.mha'}" in capsys.readouterr().err
    assert _files(tmp_path / "s") == {"talus": "talus.mha", "tibia": "calcaneus.mha"}


def test_a_name_given_twice_is_refused(lab, tmp_path, capsys):
    """--bones a,a made one bone of two CTs (the study's writer then failed on the count)."""
    assert talus(["import", str(lab), "--out", str(tmp_path / "s"), "--bones", "a,a"]) == 1
    assert "--bones: a name given twice in ['a', 'a']" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
