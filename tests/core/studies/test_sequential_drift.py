"""The sequential-drift study's bound (core.studies.tracking.sequential_drift): the acceptance JSON's
is seed 0's, so another seed from Python must compute its own, as the command line demands."""

import pytest

from core.studies.tracking import acceptance, sequential_drift


class _Built(Exception):
    """Raised where the study would build its scene: it got past the bound's check."""


def _no_scene(**kw):
    raise _Built(kw.get("seed"))


def test_another_seed_with_the_acceptance_json_bound_is_refused_before_any_work(monkeypatch):
    monkeypatch.setattr(acceptance, "tracking_scene", _no_scene)
    with pytest.raises(ValueError, match="seed 1: another trial's bound"):
        sequential_drift.run(seed=1)  # the default bound: seed 0's acceptance JSON
    with pytest.raises(ValueError, match="compute"):
        sequential_drift.run(seed=2, bound="some/acceptance.json")
    for seed, bound in ((1, "compute"), (0, sequential_drift.ACCEPTANCE_JSON), (0, "compute")):
        with pytest.raises(_Built):  # these go on to the scene
            sequential_drift.run(seed=seed, bound=bound)


def test_the_command_line_refuses_it_too(monkeypatch, capsys):
    monkeypatch.setattr(acceptance, "tracking_scene", _no_scene)
    with pytest.raises(SystemExit) as e:
        sequential_drift.main(["--seed", "1"])
    assert e.value.code == 2 and "--bound compute" in capsys.readouterr().err
    with pytest.raises(_Built):
        sequential_drift.main(["--seed", "1", "--bound", "compute"])


def test_quick_computes_its_own_bound(monkeypatch):
    # --quick's 256² scene is not the acceptance JSON's: its bound is computed unless one is given
    assert sequential_drift._default_bound(True, None) == "compute"
    assert sequential_drift._default_bound(False, None) == sequential_drift.ACCEPTANCE_JSON
    assert sequential_drift._default_bound(True, "x.json") == "x.json"
    monkeypatch.setattr(acceptance, "tracking_scene", _no_scene)
    with pytest.raises(_Built):  # a quick run of another seed needs no --bound
        sequential_drift.run(quick=True, seed=1)
