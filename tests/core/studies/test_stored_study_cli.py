"""The stored-run studies' command line (core.studies.tracking._study_cli.stored_parser): trajectory_gaps,
trajectory_pairs, trajectory_silent and trajectory_ends list --out and --machine-name (this CPU by default)
first, then their own options, as before they took the shared parser."""

from __future__ import annotations

import importlib
import re

import pytest

from core.studies.tracking import _study_cli as cli

OPTIONS = {"trajectory_gaps": ["--out", "--machine-name", "--tracks"],
           "trajectory_pairs": ["--out", "--machine-name", "--no-tune"],
           "trajectory_silent": ["--out", "--machine-name", "--no-tradeoff"],
           "trajectory_ends": ["--out", "--machine-name", "--draws"]}


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_each_stored_run_study_lists_its_options(name, capsys):
    with pytest.raises(SystemExit) as stop:
        importlib.import_module(f"core.studies.tracking.{name}").main(["--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: python -m core.studies.tracking.{name} ")
    assert re.findall(r"^  (--[a-z-]+)", text, flags=re.M) == OPTIONS[name]


def test_the_stored_parser_defaults():
    a = cli.stored_parser("trajectory_gaps", "The study.\nMore.", "the counts").parse_args([])
    assert a.out is None and a.machine_name == cli.CPU_MACHINE == "this 2-core x86_64 machine, shared"
    p = cli.stored_parser("trajectory_gaps", "The study.\nMore.", "the counts")
    assert p.description == "The study." and "write the counts as JSON here" in p.format_help()
