"""talus track --search and --scale: parsed into the registration options, bad values refused."""

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
    a = _parse(["study", "--trial", "walk"])
    assert a.search == "local" and a.scale == 1.0
    a = _parse(["study", "--trial", "walk", "--search", "newton", "--scale", "2"])
    assert a.search == "newton" and a.scale == 2.0
    with pytest.raises(SystemExit):
        _parse(["study", "--trial", "walk", "--search", "cmaes"])


@pytest.mark.parametrize("bad", ["0.5", "nan", "inf"])
def test_a_scale_below_one_is_refused_naming_the_option(tmp_path, capsys, bad):
    assert talus(["track", str(tmp_path), "--trial", "walk", "--scale", bad, "--quiet"]) == 1
    assert "--scale" in capsys.readouterr().err
