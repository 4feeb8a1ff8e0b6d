"""talus track --search, --scale, --metric and --final: parsed into the registration options, bad
values refused."""

from __future__ import annotations

import argparse

import pytest

from app.cli import main as talus
from app.commands import track


def _parse(argv):
    p = argparse.ArgumentParser()
    track.configure(p)
    return p.parse_args(argv)


def test_search_and_scale_are_parsed():
    from core.tracking.batch import TaskSettings
    from core.tracking.options import DEFAULT_SEARCH
    from core.tracking.trial import TrackingOptions

    a = _parse(["study", "--trial", "walk"])
    assert a.search == "newton" and a.scale == 1.0
    # talus track, talus batch and the tracker itself default to the same search
    assert TrackingOptions().registration.search == a.search == DEFAULT_SEARCH == track.DEFAULT_SEARCH
    assert TaskSettings().tracking_options(joint=True).registration.search == a.search
    assert track.options_from_choices().registration.search == a.search
    a = _parse(["study", "--trial", "walk", "--search", "local", "--scale", "2"])
    assert a.search == "local" and a.scale == 2.0  # the quadratic-model search stays selectable
    assert track.options_from_choices(search=a.search).registration.search == "local"
    with pytest.raises(SystemExit):
        _parse(["study", "--trial", "walk", "--search", "cmaes"])


@pytest.mark.parametrize("bad", ["0.5", "nan", "inf"])
def test_a_scale_below_one_is_refused_naming_the_option(tmp_path, capsys, bad):
    assert talus(["track", str(tmp_path), "--trial", "walk", "--scale", bad, "--quiet"]) == 1
    assert "--scale" in capsys.readouterr().err


def test_metric_is_parsed_into_the_gc_terms():
    from core.tracking.cost import DEFAULT_TERMS

    a = _parse(["study", "--trial", "walk"])
    assert a.metric == "magnitudes" and track.registration_terms(a.metric) == DEFAULT_TERMS
    a = _parse(["study", "--trial", "walk", "--metric", "components"])
    terms = track.registration_terms(a.metric)
    assert [t.kind for t in terms] == [t.kind for t in DEFAULT_TERMS]
    for t, d in zip(terms, DEFAULT_TERMS, strict=True):
        assert t.options == ({**d.options, "components": True} if t.kind == "gc" else d.options)
        assert t.weight == d.weight
    assert not any("components" in t.options for t in DEFAULT_TERMS)  # the default is unchanged
    # the older names still work: gc is the default cost, another batched kind is one term of it
    gc = _parse(["study", "--trial", "walk", "--metric", "gc"]).metric
    assert track.registration_terms(gc) == DEFAULT_TERMS
    ncc = track.registration_terms(_parse(["study", "--trial", "walk", "--metric", "ncc"]).metric)
    assert [(t.kind, t.weight) for t in ncc] == [("ncc", 1.0)]


def test_final_is_parsed_and_maps_to_the_registrations_final_stage():
    a = _parse(["study", "--trial", "walk"])
    assert a.final == "none"
    assert track.options_from_choices(final=a.final).registration.final is None
    a = _parse(["study", "--trial", "walk", "--final", "likelihood"])
    opts = track.options_from_choices(final=a.final)
    assert opts.refine_likelihood and opts.registration.final == "likelihood"
    with pytest.raises(SystemExit):
        _parse(["study", "--trial", "walk", "--final", "ml"])
    with pytest.raises(ValueError, match="final"):
        track.options_from_choices(final="ml")


def test_final_help_states_the_trade_off(capsys):
    p = argparse.ArgumentParser()
    track.configure(p)
    with pytest.raises(SystemExit):
        p.parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--final {none,likelihood}" in text
    assert "NVIDIA H200" in text and "1.50/1.42" in text and "flatfield-corrected" in text
