import json
import math
import os
import stat
import time

import pytest

from core.geometry import write_mayacam
from core.io import atomic
from core.io.atomic import FileLock, LockedError, atomic_open, atomic_write, atomic_write_json, print_json
from core.synthetic import foot_rig


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


def test_a_held_lock_relabelled_names_its_new_holder(tmp_path):
    """relabel: the holder line names what holds the lock now; the lock is never let go."""
    lock = FileLock(tmp_path / ".lock", purpose="study X", by="a script").acquire()
    other = FileLock(tmp_path / ".lock", purpose="study X")
    lock.relabel("talus track")
    assert lock.locked and lock.read_holder()["by"] == "talus track"
    with pytest.raises(LockedError, match=r"\(talus track\)"):
        other.acquire()
    lock.release()
    with pytest.raises(ValueError, match="relabel needs the lock held"):
        lock.relabel("talus track")


def test_a_relabelled_lock_always_names_a_holder(tmp_path):
    """The holder line is rewritten in place (the lock belongs to the file: no new file renamed
    over it): the new line over the old, then the old one's longer tail cut. A reader in between
    gets the new holder, not nothing; one reading while the line is relabelled over and over never
    reads an empty holder (it did: the line was cut to nothing first, then written)."""
    import threading

    lock = FileLock(tmp_path / ".lock", purpose="study X", by="a script with a long name").acquire()
    path = tmp_path / ".lock"
    old = path.read_bytes()
    new = json.dumps({"pid": 1, "by": "short"}).encode()
    assert len(new) < len(old)
    path.write_bytes(new + old[len(new):])  # the new line written, the old tail not yet cut
    assert FileLock(path).read_holder() == {"pid": 1, "by": "short"}
    seen, stop = [], threading.Event()

    def read():
        other = FileLock(path)
        while not stop.is_set():
            seen.append(other.read_holder().get("by"))

    reader = threading.Thread(target=read)
    reader.start()
    try:
        for k in range(400):
            lock.relabel("a" if k % 2 else "a much longer name of what holds it " * 3)
    finally:
        stop.set()
        reader.join()
    lock.release()
    assert seen and None not in seen


def test_a_lock_just_taken_is_read_again_for_its_holder(tmp_path, monkeypatch):
    """Refused by a lock taken a moment ago, whose holder line is not yet written (the file empty:
    released locks are cut to nothing), a writer reads it again after a moment."""
    path = tmp_path / ".lock"
    lock = FileLock(path, by="talus track").acquire()
    line = path.read_bytes()
    path.write_bytes(b"")
    monkeypatch.setattr(time, "sleep", lambda s: path.write_bytes(line))  # the holder writes meanwhile
    with pytest.raises(LockedError) as refused:
        FileLock(path).acquire()
    monkeypatch.undo()
    lock.release()
    assert refused.value.holder.get("by") == "talus track"


@pytest.fixture(params=[0o022, 0o077, 0o002])
def umask(request):
    old = os.umask(request.param)
    yield request.param
    os.umask(old)


def test_new_files_get_the_mode_a_plain_open_gives(tmp_path, umask):
    """mkstemp alone makes 0600 files: a lab's shared study folder became unreadable to others."""
    want = 0o666 & ~umask
    with open(tmp_path / "plain", "w"):
        pass
    assert stat.S_IMODE((tmp_path / "plain").stat().st_mode) == want
    atomic_write(tmp_path / "a.json", "x")
    with atomic_open(tmp_path / "b.bin", "wb") as fh:
        fh.write(b"x")
    with atomic.atomic_path(tmp_path / "c.npy") as tmp:
        tmp.write_bytes(b"x")
    write_mayacam(foot_rig(seed=1, pixels=16)[0], tmp_path / "cam.txt")
    for name in ("a.json", "b.bin", "c.npy", "cam.txt"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == want, name
    os.chmod(tmp_path / "a.json", 0o640)  # a replaced file keeps its mode, as with open("w")
    atomic_write(tmp_path / "a.json", "y")
    write_mayacam(foot_rig(seed=1, pixels=16)[1], tmp_path / "cam.txt")
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o640
    assert stat.S_IMODE((tmp_path / "cam.txt").stat().st_mode) == want


def test_remove_stale_temporaries(tmp_path):
    old = time.time() - 3600
    (tmp_path / "sub").mkdir()
    stale = [tmp_path / ".study.json.ab_cd123.tmp", tmp_path / "sub" / ".vol.x1y2z3w4.tmp.npy"]
    fresh = tmp_path / ".study.json.zz9yy8xx.tmp"  # a live writer's: too young
    others = [tmp_path / "study.json", tmp_path / ".notes.tmp", tmp_path / "keep.tmp"]
    for p in [*stale, fresh, *others]:
        p.write_text("x")
    for p in [*stale, *others]:
        os.utime(p, (old, old))
    outside = tmp_path.parent / f"{tmp_path.name}_outside"
    outside.mkdir()
    (outside / ".a.json.12345678.tmp").write_text("x")
    os.utime(outside / ".a.json.12345678.tmp", (old, old))
    (tmp_path / "link").symlink_to(outside)  # never followed
    removed = atomic.remove_stale_temporaries(tmp_path, older_than_s=600)
    assert sorted(removed) == sorted(stale)
    assert fresh.exists() and all(p.exists() for p in others)
    assert (outside / ".a.json.12345678.tmp").exists()
    assert atomic.remove_stale_temporaries(tmp_path, older_than_s=0) == [fresh]


def test_json_checkpoint_writes_each_partial_result_with_its_fields(tmp_path):
    out = tmp_path / "study.json"
    checkpoint = atomic.json_checkpoint(out, indent=1, machine_name="one GPU", empty=None)
    res = {"frames_done": 1, "rms": float("nan")}
    checkpoint(res)
    assert res["machine_name"] == "one GPU" and "empty" not in res  # fields with a value only
    text = out.read_text()
    assert text.endswith("\n") and text == json.dumps(res, indent=1) + "\n"  # NaN kept, as studies write
    assert math.isnan(json.loads(text)["rms"])
    res["frames_done"] = 2
    checkpoint(res)
    assert json.loads(out.read_text())["frames_done"] == 2
    nowhere = {"a": 1}
    atomic.json_checkpoint(None, machine_name="x")(nowhere)  # no file: the fields still set
    assert nowhere == {"a": 1, "machine_name": "x"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study.json"]


def test_a_lock_whose_holder_cannot_be_written_is_not_kept(tmp_path, monkeypatch):
    """Writing the holder's line failed (e.g. a full disk) after the lock was taken: the error is
    raised and the lock let go. Its open file kept it taken for the process's life (a window's edits
    of a bone, and a batch's tasks of it, refused until the window closed)."""

    def full(fd):
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as m:
        m.setattr(os, "fsync", full)
        with pytest.raises(OSError, match="No space left"):
            FileLock(tmp_path / ".lock", purpose="bone").acquire()
    FileLock(tmp_path / ".lock", purpose="bone").acquire().release()  # free
