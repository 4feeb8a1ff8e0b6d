"""Crash safety and locking between processes (real child interpreters, SIGKILL mid-write)."""

import json
import random
import signal
import sys
import time

import numpy as np
import pytest

from core.study import LockedError, Study, read_journal

HOLD = """
import time
from core.study import Study
st = Study.open({folder!r}, mode="w")
st.lock_journal("walk01", "talus")
print("ready", flush=True)
time.sleep(600)  # killed by the test
"""


@pytest.fixture
def folder(talus_study):
    return talus_study


def test_two_writers_of_one_bone_get_a_clear_error(folder, python_child):
    child = python_child.start(HOLD.format(folder=str(folder)))
    assert child.stdout.readline().strip() == "ready"
    held = rf"bone 'talus' of trial 'walk01' in study .*st is locked for writing by process {child.pid} on "
    with Study.open(folder, mode="w") as st:  # the study itself is not locked ...
        with pytest.raises(LockedError, match=held):  # ... the bone's journal is
            st.lock_journal("walk01", "talus")
        with pytest.raises(LockedError, match=held):
            st.trial("walk01").record_pose("talus", 0, np.eye(4))
    with Study.open(folder) as ro:  # readers are not blocked
        assert ro.trials == ("walk01",)
    child.kill()  # the kernel releases the lock of a dead process
    child.wait(timeout=30)
    with Study.open(folder, mode="w") as st:
        st.lock_journal("walk01", "talus")
        # and now a second process is the one refused
        out = python_child.run(
            f"""
            from core.study import Study, LockedError
            try:
                Study.open({str(folder)!r}, mode="w").lock_journal("walk01", "talus")
            except LockedError as exc:
                print("refused:", exc)
            """
        )
        assert "refused:" in out.stdout and "locked for writing" in out.stdout


WRITER = """
import numpy as np
from core.study import Study
from core.geometry import make_rigid
st = Study.open({folder!r}, mode="w")
tr = st.trial("walk01")
i = {start}
while True:
    tr.record_pose("talus", i % 6, make_rigid(np.eye(3), [i, 0.5 * i, -i]), score=i / 1000)
    st.update_settings(counter=i, padding="x" * 20000)
    print(i, flush=True)
    i += 1
"""


@pytest.mark.skipif(sys.platform.startswith("win"), reason="SIGKILL semantics are POSIX")
def test_kill_writer_mid_write_leaves_previous_valid_state(folder, python_child):
    rng = random.Random(7)
    start = 0
    for _ in range(3):
        child = python_child.start(WRITER.format(folder=str(folder), start=start))
        last = -1
        while last < start + 15:  # let it complete a few operations
            line = child.stdout.readline()
            assert line, child.stderr.read()
            last = int(line)
        time.sleep(rng.uniform(0.0, 0.03))
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
        for line in child.stdout.read().split():  # operations acknowledged before the kill
            last = int(line)
        with Study.open(folder, mode="w") as st:  # lock released; manifest valid
            counter = st.settings["counter"]
            assert last <= counter <= last + 1  # every acknowledged write survived
            state = st.trial("walk01").results("talus")
            P = st.trial("walk01").poses("talus")
            for f in range(6):
                i = int(P[f, 0, 3])
                assert i % 6 == f and i <= last + 1
                np.testing.assert_array_equal(P[f, :3, 3], [i, 0.5 * i, -i])
            assert max(int(P[f, 0, 3]) for f in range(6)) >= last
            assert json.loads((folder / "study.json").read_text())["settings"]["counter"] == counter
            start = counter + 1
        assert read_journal(folder / "results" / "walk01" / "poses" / "talus.jsonl").n_lines == state.n_lines
