"""core.io.read_session: layout checks and errors on small hand-made sessions."""

import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import tifffile

from core.errors import FileError
from core.io import CalibrationSession, read_session

H, W = 12, 16


def _frame(value=100, shape=(H, W), dtype=np.uint16):
    return np.full(shape, value, dtype=dtype)


def make_session(root: Path, *, cameras=("cam1", "cam2"), kvs=("70",), counts=None,
                 with_truth=True, **manifest_extra) -> Path:
    counts = {"dark": 2, "grid": 3, "cube": 1, "spiral": 4, **(counts or {})}
    groups = {"dark": "dark", "flat": {kv: f"flat_{kv}kV" for kv in kvs}, "grid": "grid",
              "cube": "cube", "spiral": "spiral"}
    folders = {"dark": counts["dark"], "grid": counts["grid"], "cube": counts["cube"],
               "spiral": counts["spiral"], **{f"flat_{kv}kV": 2 for kv in kvs}}
    for cam in cameras:
        for folder, n in folders.items():
            (root / cam / folder).mkdir(parents=True, exist_ok=True)
            for i in range(n):
                tifffile.imwrite(root / cam / folder / f"{i:04d}.tif", _frame(100 + i))
    manifest = {"format": "talus-calibration-session", "version": 1, "cameras": list(cameras),
                "bit_depth": 12, "frame_size": [H, W], "groups": groups,
                "grid": {"kind": "hole", "pitch_mm": 15.0},
                "objects": {"cube": "cube15", "spiral": "spiral33"}, "notes": "test",
                "n_frames": folders}
    manifest.update(manifest_extra)
    (root / "session.json").write_text(json.dumps(manifest))
    if with_truth:
        (root / "truth").mkdir()
        (root / "truth" / "truth.json").write_text("{}")
        np.savez(root / "truth" / "truth.npz", x=np.zeros(3))
    return root


def _edit_manifest(root: Path, **changes):
    m = json.loads((root / "session.json").read_text())
    for k, v in changes.items():
        if v is None:
            m.pop(k, None)
        else:
            m[k] = v
    (root / "session.json").write_text(json.dumps(m))


def test_reads_a_session(tmp_path):
    root = make_session(tmp_path / "s", kvs=("70", "80.5"))
    s = read_session(root)
    assert isinstance(s, CalibrationSession)
    assert s.root == root and s.cameras == ("cam1", "cam2") and s.bit_depth == 12
    assert s.frame_size == (H, W) and s.kvs == (70.0, 80.5)
    assert s.objects == {"cube": "cube15", "spiral": "spiral33"}
    assert s.manifest["grid"] == {"kind": "hole", "pitch_mm": 15.0}
    assert s.groups == ("dark", "flat:70", "flat:80.5", "grid", "cube", "spiral")
    spiral = s.frames("cam2", "spiral")
    assert spiral == [root / "cam2" / "spiral" / f"{i:04d}.tif" for i in range(4)]
    img = s.read(spiral[3])
    assert img.dtype == np.float32 and img.shape == (H, W) and np.all(img == 103)
    assert s.stack("cam1", "grid").shape == (3, H, W)
    assert s.frames("cam1", "flat:80.5") == sorted((root / "cam1" / "flat_80.5kV").glob("*.tif"))
    assert s.frames("cam1", "flat:70.0") == s.frames("cam1", "flat:70")
    assert read_session(root / "session.json").root == root
    assert s.has("grid") and not s.has("lattice")
    s.require("dark", "grid", "spiral")
    with pytest.raises(FileError, match=r"session.json: the session lacks \['lattice'\]"):
        s.require("grid", "lattice")
    with pytest.raises(ValueError, match="'flat:<kV>'"):
        s.frames("cam1", "flat")  # two voltages: say which
    with pytest.raises(ValueError, match="no empty-field frames at 90 kV"):
        s.frames("cam1", "flat:90")
    with pytest.raises(ValueError, match="camera: expected one of"):
        s.frames("cam3", "grid")
    with pytest.raises(ValueError, match="group: expected one of"):
        s.frames("cam1", "walk")
    with pytest.raises(ValueError, match="lists no 'lattice' group"):
        s.frames("cam1", "lattice")


def test_single_kv_flat_and_extra_fields(tmp_path):
    root = make_session(tmp_path / "s", kv=70.0, detector={"field_mm": 300.0})
    s = read_session(root)
    assert s.frames("cam1", "flat") == s.frames("cam1", "flat:70")
    assert s.manifest["detector"] == {"field_mm": 300.0}


def test_missing_view(tmp_path):
    root = make_session(tmp_path / "s")
    (root / "cam2").rename(root / "camB")
    with pytest.raises(FileError, match=r"cam2: missing view folder; .*session.json lists cameras"):
        read_session(root)


def test_missing_group_folder_and_empty_group(tmp_path):
    root = make_session(tmp_path / "s")
    for p in (root / "cam1" / "grid").iterdir():
        p.unlink()
    with pytest.raises(FileError, match=r"cam1/grid: no frames \(.tif\) in the grid group"):
        read_session(root)
    (root / "cam1" / "grid").rmdir()
    with pytest.raises(FileError, match=r"cam1/grid: missing grid group folder of view 'cam1'"):
        read_session(root)


def test_frames_of_different_sizes(tmp_path):
    root = make_session(tmp_path / "s")
    bad = root / "cam2" / "spiral" / "0002.tif"
    tifffile.imwrite(bad, _frame(shape=(H, W + 2)))
    with pytest.raises(FileError, match=r"0002.tif: frame of 12x18 \(H x W\); expected 12x16") as e:
        read_session(root)
    assert e.value.path == bad


def test_wrong_bit_depth(tmp_path):
    root = make_session(tmp_path / "s")
    tifffile.imwrite(root / "cam1" / "dark" / "0000.tif", _frame(dtype=np.uint8))
    with pytest.raises(FileError, match=r"dark/0000.tif: uint8 holds 8 bits, fewer than the bit_depth 12"):
        read_session(root)
    tifffile.imwrite(root / "cam1" / "dark" / "0000.tif", _frame().astype(np.float32))
    with pytest.raises(FileError, match="expected raw unsigned integer counts"):
        read_session(root)
    tifffile.imwrite(root / "cam1" / "dark" / "0000.tif", _frame(5000))
    s = read_session(root)  # counts are checked when the frame is read
    with pytest.raises(FileError, match=r"0000.tif: counts up to 5000 exceed the 12-bit range"):
        s.read(s.frames("cam1", "dark")[0])
    _edit_manifest(root, bit_depth=24)
    with pytest.raises(FileError, match=r"session.json: 'bit_depth' must be an integer in 1..16"):
        read_session(root)


def test_frame_counts(tmp_path):
    root = make_session(tmp_path / "s")
    (root / "cam2" / "spiral" / "0003.tif").unlink()
    with pytest.raises(FileError, match=r"cam2/spiral: 3 frames; .*session.json says n_frames 4"):
        read_session(root)
    _edit_manifest(root, n_frames=None)
    with pytest.raises(FileError, match=r"the spiral group has \{'cam1': 4, 'cam2': 3\} frames per view"):
        read_session(root)


@pytest.mark.parametrize("change, message", [
    ({"format": "talus-synthetic-study"}, "format 'talus-synthetic-study'; expected"),
    ({"version": 9}, "version 9; this Talus reads versions"),
    ({"cameras": []}, "'cameras' must list distinct view folder names"),
    ({"cameras": ["../x"]}, "camera '../x' is not a plain folder name"),
    ({"frame_size": [12]}, r"'frame_size' must be \[H, W\]"),
    ({"groups": {"darks": "dark"}}, "unknown group 'darks'"),
    ({"groups": {"flat": "flat_70kV"}}, "groups.flat must map kV to folders"),
    ({"groups": {"flat": {"seventy": "f"}}}, "groups.flat key 'seventy' is not a tube voltage"),
    ({"groups": {"grid": "../grid"}}, "groups.grid folder must be a plain folder name"),
])
def test_bad_manifest(tmp_path, change, message):
    root = make_session(tmp_path / "s")
    _edit_manifest(root, **change)
    with pytest.raises(FileError, match=message) as e:
        read_session(root)
    assert e.value.path == root / "session.json"


def test_no_or_broken_manifest(tmp_path):
    with pytest.raises(FileError, match="not a calibration session folder"):
        read_session(tmp_path / "nowhere")
    (tmp_path / "s").mkdir()
    with pytest.raises(FileError, match=r"session\.json: missing"):
        read_session(tmp_path / "s")
    (tmp_path / "s" / "session.json").write_text("{not json")
    with pytest.raises(FileError, match=r"session\.json: not readable JSON"):
        read_session(tmp_path / "s")
    root = make_session(tmp_path / "t")
    (root / "cam1" / "cube" / "0000.tif").write_bytes(b"II*\x00garbage")
    with pytest.raises(FileError, match=r"cube/0000.tif: cannot read the frame as TIFF"):
        read_session(root)


_watch: dict = {"on": False, "hits": [], "installed": False}
_lock = threading.Lock()


def _audit(event, args):
    if not _watch["on"] or event not in ("open", "os.listdir", "os.scandir"):
        return
    path = args[0] if args else None
    if isinstance(path, (str, bytes, Path)) and "truth" in Path(str(path if not isinstance(path, bytes)
                                                                    else path.decode())).parts:
        with _lock:
            _watch["hits"].append((event, str(path)))


def test_reader_never_touches_truth(tmp_path):
    if not _watch["installed"]:  # audit hooks cannot be removed: install one, idle unless "on"
        sys.addaudithook(_audit)
        _watch["installed"] = True
    root = make_session(tmp_path / "s")
    _watch["hits"].clear()
    _watch["on"] = True
    try:
        s = read_session(root)
        for cam in s.cameras:
            for g in s.groups:
                s.stack(cam, g)
    finally:
        _watch["on"] = False
    assert _watch["hits"] == []
    # the audit hook does see a read of truth/
    _watch["on"] = True
    try:
        (root / "truth" / "truth.json").read_text()
    finally:
        _watch["on"] = False
    assert _watch["hits"] and _watch["hits"][0][0] == "open"


def test_reader_imports_no_generator():
    code = ("import sys, core.io.calibration_session; "
            "print([m for m in sys.modules if m.startswith('core.synthetic')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
