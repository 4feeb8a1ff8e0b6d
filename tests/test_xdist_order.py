"""tests/conftest.py's xdist scheduler (``--dist loadgroup``): the groups go to the workers longest
first by the seconds their files took in the last run (pytest's cache), xdist's order by number of
tests without that record; a group's tests stay in one worker."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

pytest.importorskip("xdist")

import tests.conftest as conftest

# three groups: a.py (4 short tests), b.py + c.py (one group, 1 long test each), d.py (2 tests)
COLLECTION = [*(f"tests/a.py::t{i}" for i in range(4)), "tests/b.py::t", "tests/c.py::t",
              "tests/d.py::t0", "tests/d.py::t1"]
GROUPS = {"tests/a.py": "tests/a.py", "tests/b.py": "fixture x", "tests/c.py": "fixture x",
          "tests/d.py": "tests/d.py"}


class _Cache:
    def __init__(self, seconds):
        self.seconds = seconds

    def get(self, key, default):
        return self.seconds if key == conftest._SECONDS_KEY and self.seconds is not None else default


class _Node:
    shutting_down = False

    def __init__(self, name):
        self.name, self.sent, self.gateway = name, [], SimpleNamespace(id=name)

    def send_runtest_some(self, indices):
        self.sent.append([COLLECTION[i] for i in indices])

    def shutdown(self):
        self.shutting_down = True


def _first_units(seconds, tmp_path, monkeypatch):
    groups_file = tmp_path / "groups.json"
    groups_file.write_text(json.dumps(GROUPS))
    monkeypatch.setenv(conftest._GROUPS_FILE, str(groups_file))
    values = {"dist": "loadgroup", "tx": ["2*popen"]}
    config = SimpleNamespace(getvalue=values.__getitem__, cache=_Cache(seconds),
                             option=SimpleNamespace(loadscopereorder=True))
    sched = conftest.pytest_xdist_make_scheduler(config, None)
    nodes = [_Node("gw0"), _Node("gw1")]
    for n in nodes:
        sched.add_node(n)
    for n in nodes:
        sched.add_node_collection(n, COLLECTION)
    sched.schedule()
    return [[sorted({t.split("::")[0] for t in unit}) for unit in n.sent] for n in nodes]


def test_longest_groups_first_by_the_last_runs_seconds(tmp_path, monkeypatch):
    seconds = {"tests/a.py": 2.0, "tests/b.py": 30.0, "tests/c.py": 25.0, "tests/d.py": 9.0}
    gw0, gw1 = _first_units(seconds, tmp_path, monkeypatch)
    # the 55 s group first, then the 9 s file, the 2 s file last; b.py and c.py in one unit
    assert gw0[0] == ["tests/b.py", "tests/c.py"] and gw1[0] == ["tests/d.py"]
    assert [["tests/a.py"]] in (gw0[1:], gw1[1:])


def test_a_new_file_counts_as_its_tests_at_the_mean_time(tmp_path, monkeypatch):
    # d.py not in the record: 2 tests at the mean (40 s over 8 tests) -> 10 s, before a.py's 1 s
    gw0, gw1 = _first_units({"tests/a.py": 1.0, "tests/b.py": 20.0, "tests/c.py": 19.0},
                            tmp_path, monkeypatch)
    assert gw0[0] == ["tests/b.py", "tests/c.py"] and gw1[0] == ["tests/d.py"]


def test_without_a_record_xdist_orders_by_number_of_tests(tmp_path, monkeypatch):
    gw0, gw1 = _first_units(None, tmp_path, monkeypatch)
    assert gw0 == [["tests/a.py"]]  # 4 tests
    assert gw1 == [["tests/b.py", "tests/c.py"], ["tests/d.py"]]  # 2 tests each, in collection order
