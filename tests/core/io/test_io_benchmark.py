from core.studies.io.benchmark import main, run


def test_quick_benchmark_runs_and_verifies_frames(tmp_path, capsys):
    r = run(quick=True, folder=tmp_path)
    assert r["sizes"]["frames"] == 50 and r["machine"]["cpu_count"] >= 1
    for name in ("cine_p12", "tiff_uint16"):
        for case in ("warm", "cold"):
            res = r["results"][name][case]
            if "skipped" not in res:
                assert res["frames_verified"] and res["random_frames"] == 20
    assert r["results"]["tiff_uint16"]["memory_mapped"]
    assert not list(tmp_path.iterdir())  # temporary files removed
    assert main(["--quick", "--dir", str(tmp_path), "--out", str(tmp_path / "b.json")]) == 0
    assert '"benchmark": "core.io sequence read"' in capsys.readouterr().out
    assert (tmp_path / "b.json").is_file()
