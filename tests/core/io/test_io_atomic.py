import json
import math

import pytest

from core.io import atomic
from core.io.atomic import FileLock, LockedError, atomic_open, atomic_write, atomic_write_json, print_json


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_atomic_write_replaces_content(tmp_path):
    p = tmp_path / "a.json"
    atomic_write(p, "old")
    atomic_write(p, b"new bytes")
    assert p.read_bytes() == b"new bytes"
    atomic_write_json(p, {"x": [1, 2.5], "s": "é"})
    assert json.loads(p.read_text(encoding="utf-8")) == {"x": [1, 2.5], "s": "é"}
    assert _leftovers(tmp_path) == []


def test_failure_between_write_and_rename_keeps_old_file(tmp_path, monkeypatch):
    p = tmp_path / "m.json"
    atomic_write(p, "previous valid state")

    def boom(src, dst):
        raise OSError("disk full (injected between write and rename)")

    monkeypatch.setattr(atomic.os, "replace", boom)
    with pytest.raises(OSError, match="injected"):
        atomic_write(p, "x" * 100_000)
    monkeypatch.undo()
    assert p.read_text() == "previous valid state"
    assert _leftovers(tmp_path) == []


def test_exception_inside_block_keeps_old_file(tmp_path):
    p = tmp_path / "m.bin"
    atomic_write(p, b"v1")
    with pytest.raises(RuntimeError, match="half"):
        with atomic_open(p, "wb") as fh:
            fh.write(b"v2 partial")
            raise RuntimeError("crashed half way")
    assert p.read_bytes() == b"v1"
    assert _leftovers(tmp_path) == []


def test_json_rejects_nan_and_writes_nothing(tmp_path):
    p = tmp_path / "r.json"
    with pytest.raises(ValueError, match=r"r\.json: cannot be written as strict JSON"):
        atomic_write_json(p, {"score": math.nan})
    assert not p.exists() and _leftovers(tmp_path) == []


def test_print_json_prints_and_optionally_writes(tmp_path, capsys):
    obj = {"fps": 26.4, "missing": float("nan")}  # benchmark JSON may carry NaN
    print_json(obj)
    assert capsys.readouterr().out == json.dumps(obj, indent=2) + "\n"
    out = tmp_path / "r.json"
    print_json(obj, out)
    assert out.read_text() == capsys.readouterr().out == json.dumps(obj, indent=2) + "\n"


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="mode"):
        with atomic_open(tmp_path / "x", "a"):
            pass
    with pytest.raises(ValueError, match="does not exist"):
        atomic_write(tmp_path / "nofolder" / "x", "t")
    with pytest.raises(ValueError, match="data"):
        atomic_write(tmp_path / "x", 3)


def test_lock_is_exclusive_and_names_the_holder(tmp_path):
    lock = FileLock(tmp_path / ".lock", purpose="study X").acquire()
    other = FileLock(tmp_path / ".lock", purpose="study X")
    with pytest.raises(LockedError, match=r"study X is locked for writing by process \d+") as err:
        other.acquire()
    assert err.value.holder["pid"] > 0
    lock.release()
    lock.release()  # idempotent
    with other:
        assert other.locked
    assert not other.locked
