"""Property-based fuzzing of the manifest validator/migrations and the pose journal reader."""

import copy
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.study import StudyError, read_journal
from core.study.manifest import new_manifest
from core.study.migrations import migrate
from core.study.results import append_pose
from core.study.schema import validate_manifest

TRIED = {"manifest": 0, "manifest_v1": 0, "journal": 0}
OUTCOME = {"accepted": 0, "rejected": 0}
FUZZ = settings(max_examples=300, deadline=None, database=None)

JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 5) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=6,
)


def _valid():
    doc = new_manifest("fuzz")
    doc["calibrations"]["day1"] = {"format": "mayacam", "cameras": ["a.txt", "b.txt"], "pixel_size_mm": None}
    ct = {"path": "ct.nii.gz", "voxel_size_mm": None, "hu_offset": 0.0, "labels": "l.nii.gz"}
    doc["volumes"]["ct"] = ct
    doc["bones"]["talus"] = {"volume": "ct", "label": 3, "margin_mm": 5.0}
    doc["trials"]["walk"] = {"calibration": "day1", "views": [{"path": "1.cine", "bit_depth": 12},
                                                              {"path": "2.cine"}], "frame_offset": 0,
                             "bones": ["talus"]}
    return doc


def _v1():
    return {"format": "talus-study", "schema_version": 1, "name": "old", "cameras": ["a", "b"],
            "bones": [{"name": "talus", "ct": "ct.nii", "label": 1}],
            "trials": [{"name": "t", "views": ["1.cine", "2.cine"], "offset": 2}], "settings": {}}


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


@st.composite
def mutated_doc(draw, base):
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if draw(st.booleans()):
            parent[path[-1]] = draw(JSON)
        elif isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent.pop(path[-1])
    return doc


def _check(doc, kind):
    TRIED[kind] += 1
    try:
        out, _ = migrate(doc)
        validate_manifest(out)
    except StudyError:
        OUTCOME["rejected"] += 1
    else:
        OUTCOME["accepted"] += 1
        json.dumps(out, allow_nan=False)  # an accepted manifest is always writable


@FUZZ
@given(doc=mutated_doc(_valid()))
def test_manifest_mutations(doc):
    _check(doc, "manifest")


@FUZZ
@given(doc=mutated_doc(_v1()))
def test_v1_manifest_mutations(doc):
    _check(doc, "manifest_v1")


@pytest.fixture(scope="module")
def journal(tmp_path_factory):
    d = tmp_path_factory.mktemp("journal")
    p = d / "good.jsonl"
    for k in range(4):
        append_pose(p, k, np.eye(4), score=0.5)
    return d, p.read_bytes()


@FUZZ
@given(data=st.data())
def test_journal_damage(journal, data):
    folder, good = journal
    blob = bytearray(good)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, 1 << 20)) % len(blob)
        if data.draw(st.booleans()):
            blob[i] = data.draw(st.integers(0, 255))
        else:
            del blob[i:]
            break
    TRIED["journal"] += 1
    p = folder / f"j{TRIED['journal']}.jsonl"
    p.write_bytes(bytes(blob))
    try:
        state = read_journal(p)
    except StudyError:
        OUTCOME["rejected"] += 1
        return
    OUTCOME["accepted"] += 1
    assert set(state.records) <= {0, 1, 2, 3}  # never invents frames (checksums)


def test_zz_report_counts():
    print(f"study fuzz: {TRIED} = {sum(TRIED.values())} inputs; {OUTCOME}")
    assert sum(TRIED.values()) == 0 or OUTCOME["rejected"] > 0
