"""A study from a lab's collection folder: what is found, the detected bit depth (a 12-bit trial
stored in 16-bit TIFFs is normalised by 4095 and tracks), and bad input named with nothing written."""

import json
import shutil

import numpy as np
import pytest
import tifffile

from core.io.bitdepth import detect_bit_depth, usable_fraction
from core.study import Study
from core.study.import_folder import ImportFolderError, make_study_from_folder, scan_folder


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("demo") / "demo"
    make_demo_study(out, n_frames=2, pixels=64, spacing=4.0, tissue_spacing=8.0, device="cpu",
                    calibration_session=False)
    return out


def lab_folder(demo, dest, *, bones=("talus",)):
    """What a lab has after a collection: two frame folders, two MayaCam files, one CT per bone."""
    (dest / "cameras").mkdir(parents=True)
    for src in sorted((demo / "frames").iterdir()):
        shutil.copytree(src, dest / "fluoro" / src.name)
        shutil.copy(demo / "rig" / f"{src.name}.txt", dest / "cameras" / f"{src.name}.txt")
    (dest / "ct").mkdir()
    for b in bones:
        shutil.copy(demo / "volumes" / f"{b}.mha", dest / "ct" / f"{b}.mha")
    return dest


def test_bit_depth_of_a_12_bit_trial_in_16_bit_tiffs(demo, tmp_path):
    folder = next((demo / "frames").iterdir())
    bd = detect_bit_depth(folder)
    assert bd.container == 16 and bd.bits == 12 and bd.source == "maximum" and not bd.certain
    assert bd.max_value <= 4095 and "confirm" in bd.text
    frame = tifffile.imread(next(folder.iterdir()))
    assert usable_fraction(frame, 12) > 0.5 > usable_fraction(frame, 16)
    # a TIFF that says so in its tags
    p = tmp_path / "tagged"
    p.mkdir()
    for k in range(2):
        tifffile.imwrite(p / f"{k}.tif", np.full((8, 8), 100 + k, np.uint16),
                         extratags=[(281, 3, 1, 1023, True)])
    got = detect_bit_depth(p)
    assert (got.bits, got.source, got.certain) == (10, "TIFF tags", True)


def test_import_and_track(demo, tmp_path):
    lab = lab_folder(demo, tmp_path / "lab")
    scan = scan_folder(lab)
    assert not scan.problems and not scan.warnings, scan.summary()
    assert [v.path.name for v in scan.views] == ["cam01", "cam02"] and scan.bit_depth == 12
    assert scan.camera_format == "mayacam" and list(scan.bones()) == ["talus"]
    assert "bit depth of fluoro/cam01" in scan.questions  # guessed from the values: to be confirmed
    out = make_study_from_folder(scan, tmp_path / "study")
    with Study.open(out, mode="w") as st:
        assert st.manifest["trials"]["trial1"]["views"][0]["bit_depth"] == 12
        assert json.loads((out / "study.json").read_text())["trials"]["trial1"]["bones"] == ["talus"]
        truth = np.load(demo / "poses" / "talus.npy")  # the user's starting pose (as posed in the window)
        st.trial("trial1").record_pose("talus", 0, truth[0])
        from core.tracking.from_study import frame_reader, track_study
        from core.tracking.trial import TrackingOptions

        read, how = frame_reader(st, st.trial("trial1"))
        assert how == "full scale (no flatfield)" and float(np.median(read(0)[0])) > 0.1
        _, report = track_study(st, "trial1", ["talus"], [0, 1], device="cpu",
                                options=TrackingOptions(verify_restarts=0, confidence=False))
    reasons = [f for f in report.get("flagged", []) if any("field of view" in x for x in f["flags"])]
    assert not reasons, report.get("flagged")
    assert report["summary"]["status"] == "complete"


def test_sixteen_bits_is_said_to_leave_the_view_unusable(demo, tmp_path):
    lab = lab_folder(demo, tmp_path / "lab")
    scan = scan_folder(lab, bit_depth=16)
    assert len(scan.warnings) == 2 and "suggests fewer bits than 16" in scan.warnings[0]
    assert "fluoro/cam01: only" in scan.warnings[0]


@pytest.mark.parametrize("case", ["one view", "camera size", "no bone", "frame sizes"])
def test_bad_folders_are_named_and_nothing_is_written(demo, tmp_path, case):
    lab = lab_folder(demo, tmp_path / "lab")
    if case == "one view":
        shutil.rmtree(lab / "fluoro" / "cam02")
        want = "expected two views (two folders of TIFF frames or two .cine files), found 1: fluoro/cam01"
    elif case == "camera size":
        for p in (lab / "fluoro" / "cam02").iterdir():
            tifffile.imwrite(p, tifffile.imread(p)[:48, :48])
        want = "cameras/cam02.txt: camera 2 expects 64x64-pixel frames but fluoro/cam02 has 48x48"
    elif case == "no bone":
        import SimpleITK as sitk

        img = sitk.ReadImage(str(lab / "ct" / "talus.mha"))
        sitk.WriteImage(sitk.Clamp(img, lowerBound=-1000, upperBound=50), str(lab / "ct" / "talus.mha"))
        want = "ct/talus.mha: no bone in the CT (largest value 50 HU, under 200 HU)"
    else:
        p = sorted((lab / "fluoro" / "cam01").iterdir())[1]
        tifffile.imwrite(p, tifffile.imread(p)[:32])
        want = "fluoro/cam01/: frames of different sizes: "
    scan = scan_folder(lab)
    assert any(want in q for q in scan.problems), scan.problems
    with pytest.raises(ImportFolderError, match="cannot make a study"):
        make_study_from_folder(scan, tmp_path / "study")
    assert not (tmp_path / "study").exists() and not list(tmp_path.glob(".study.*"))


def test_talus_import_folder(demo, tmp_path, capsys):
    from app.cli import main as talus

    lab = lab_folder(demo, tmp_path / "lab")
    assert talus(["import", str(lab), "--out", str(tmp_path / "st"), "--bones", "tal"]) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert doc["bit_depth"] == 12 and doc["bones"] == ["tal"] and doc["study"] == str(tmp_path / "st")
    assert "12-bit frames (cam01: 12 bits (largest value" in out.err
    with Study.open(tmp_path / "st") as st:
        assert list(st.bones) == ["tal"] and st.manifest["trials"]["trial1"]["views"][1]["bit_depth"] == 12
    shutil.rmtree(lab / "fluoro" / "cam02")
    assert talus(["import", str(lab), "--out", str(tmp_path / "st2")]) == 1
    assert "expected two views" in capsys.readouterr().err and not (tmp_path / "st2").exists()
