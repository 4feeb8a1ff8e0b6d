"""File → New study from folder…: the dialog reads a lab's folder, shows the detected bit depth
for confirmation and the usable pixels, names bad input, and makes the study with real clicks.
Set ``TALUS_SCREENSHOTS=DIR`` to keep a screenshot."""

import json
import os
import shutil
from pathlib import Path

import pytest
from PySide6 import QtCore

pytestmark = pytest.mark.gui
HUNG_MS = 30 * 60_000


PIXELS = 96  # the shared demo study's frames (tests/app/conftest.py)


@pytest.fixture(scope="module")
def lab(tmp_path_factory, demo_study):
    """A lab's folder laid out by hand from the shared demo study's files."""
    demo = demo_study
    lab = tmp_path_factory.mktemp("lab") / "lab"
    (lab / "cameras").mkdir(parents=True)
    for src in sorted((demo / "frames").iterdir()):  # 12-bit frames in 16-bit TIFFs
        shutil.copytree(src, lab / "fluoro" / src.name)
        shutil.copy(demo / "rig" / f"{src.name}.txt", lab / "cameras")
    (lab / "ct").mkdir()
    shutil.copy(demo / "volumes" / "talus.mha", lab / "ct" / "talus.mha")
    return lab


def _click(qtbot, w):
    qtbot.mouseClick(w, QtCore.Qt.MouseButton.LeftButton)


def _read(qtbot, dlg):
    with qtbot.waitSignal(dlg.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == "scan"):
        _click(qtbot, dlg.read_button)


def test_new_study_from_folder(qtbot, lab, tmp_path):
    from app.import_dialog import CT_ORIENTATION, ImportFolderDialog

    dlg = ImportFolderDialog(folder=lab)
    qtbot.addWidget(dlg)
    dlg.show()
    _read(qtbot, dlg)
    assert dlg.scan is not None and not dlg.scan.problems
    # detected from the frames' maximum: shown, to be confirmed before anything is written
    assert dlg.bits_combo.currentText() == "12" and not dlg.bits_confirm.isChecked()
    assert "largest value" in dlg.found.text() and not dlg.create_button.isEnabled()
    assert "LPS" in CT_ORIENTATION and "RAS" in CT_ORIENTATION
    assert "usable at 12 bits" in dlg.views[0].caption and "Before tracking" not in dlg.messages.text()
    # at 16 bits most of each view is unusable, and the dialog says why
    dlg.bits_combo.setCurrentText("16")
    assert "Before tracking" in dlg.messages.text() and "black at 16 bits" in dlg.messages.text()
    dlg.bits_combo.setCurrentText("12")
    _click(qtbot, dlg.bits_confirm)
    assert dlg.create_button.isEnabled()
    dlg.bones_table.item(0, 0).setText("tal")
    dlg.out_edit.setText(str(tmp_path / "study"))
    if os.environ.get("TALUS_SCREENSHOTS"):
        Path(os.environ["TALUS_SCREENSHOTS"]).mkdir(parents=True, exist_ok=True)
        assert dlg.grab().save(str(Path(os.environ["TALUS_SCREENSHOTS"]) / "new_study_from_folder.png"))
    with qtbot.waitSignal(dlg.study_created, timeout=HUNG_MS) as made:
        _click(qtbot, dlg.create_button)
    assert made.args[0] == str(tmp_path / "study")
    doc = json.loads((tmp_path / "study" / "study.json").read_text())
    assert doc["trials"]["trial1"]["views"][0]["bit_depth"] == 12 and list(doc["bones"]) == ["tal"]


def test_bad_folder_is_named_and_nothing_written(qtbot, lab, tmp_path):
    from app.import_dialog import ImportFolderDialog

    bad = tmp_path / "bad"
    shutil.copytree(lab, bad)
    shutil.rmtree(bad / "fluoro" / "cam02")
    dlg = ImportFolderDialog(folder=bad)
    qtbot.addWidget(dlg)
    _read(qtbot, dlg)
    assert "expected two views" in dlg.messages.text() and "nothing will be written" in dlg.messages.text()
    assert not dlg.create_button.isEnabled() and not (bad / "study").exists()


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*"))


def _smaller(path, rows=48, cols=56):
    import tifffile

    a = tifffile.imread(path)
    tifffile.imwrite(path, a[:rows, :cols])


def _views_of_other_sizes(lab):
    for f in sorted((lab / "fluoro" / "cam02").iterdir()):
        _smaller(f)
    return ["the views have frames of different sizes", f"fluoro/cam01 {PIXELS}x{PIXELS}",
            "fluoro/cam02 56x48"]


def _one_frame_smaller(lab):
    first = sorted((lab / "fluoro" / "cam01").iterdir())[0]
    _smaller(first)
    return ["fluoro/cam01/: frames of different sizes", f"1 of 56x48 pixels (e.g. {first.name})"]


def _cameras_not_matching(lab):
    for cam in ("cam01", "cam02"):
        for f in sorted((lab / "fluoro" / cam).iterdir()):
            _smaller(f, 60, 60)
    return [f"cameras/cam01.txt: camera 1 expects {PIXELS}x{PIXELS}-pixel frames but fluoro/cam01 has 60x60",
            f"cameras/cam02.txt: camera 2 expects {PIXELS}x{PIXELS}-pixel frames"]


def _ct_without_bone(lab):
    import SimpleITK as sitk

    ct = lab / "ct" / "talus.mha"
    img = sitk.ReadImage(str(ct))
    soft = sitk.GetImageFromArray(sitk.GetArrayFromImage(img).clip(-1000, 80))
    soft.CopyInformation(img)
    sitk.WriteImage(soft, str(ct))
    return ["ct/talus.mha: no bone in the CT (largest value 80 HU, under 200 HU)"]


@pytest.mark.parametrize("spoil", [_views_of_other_sizes, _one_frame_smaller, _cameras_not_matching,
                                   _ct_without_bone], ids=lambda f: f.__name__.strip("_"))
def test_bad_input_says_what_and_where_and_writes_nothing(qtbot, lab, tmp_path, spoil):
    """Frames of different sizes (between the views, within a view), cameras that do not match the
    frames' size, a CT without bone: the dialog lists the problem naming the file, Create stays
    off, and nothing is written (not even when asked to create)."""
    from app.import_dialog import ImportFolderDialog

    bad = tmp_path / "bad"
    shutil.copytree(lab, bad)
    expected = spoil(bad)
    before = _files(tmp_path)
    dlg = ImportFolderDialog(folder=bad)
    qtbot.addWidget(dlg)
    dlg.show()
    _read(qtbot, dlg)
    text = dlg.messages.text()
    assert "Cannot make a study (nothing will be written)" in text
    for part in expected:
        assert part in text, text
    assert not dlg.create_button.isEnabled()
    _click(qtbot, dlg.bits_confirm)  # even with the bit depth confirmed
    assert not dlg.create_button.isEnabled()
    dlg.out_edit.setText(str(tmp_path / "study"))
    dlg.create()  # refused: no job, nothing written
    assert "Creating" not in dlg.messages.text()
    assert _files(tmp_path) == before and not (tmp_path / "study").exists()
