"""``talus bench review --help`` and ``python -m app.benchmark_review --help`` each show their
own name (``main(argv, prog=...)``, as the other bench modules)."""

from __future__ import annotations

import pytest

from app.cli import main


def test_bench_review_help_names_itself(capsys):
    from app import benchmark_review

    with pytest.raises(SystemExit) as exc:
        main(["bench", "review", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: talus bench review [-h]") and "--refresh-every" in out
    with pytest.raises(SystemExit) as exc:
        benchmark_review.main(["--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith("usage: python -m app.benchmark_review [-h]")
    with pytest.raises(SystemExit) as exc:  # a bad option names the command it was given to
        main(["bench", "review", "--frames", "1"])
    assert exc.value.code == 2
    assert "talus bench review: error: --frames" in capsys.readouterr().err
