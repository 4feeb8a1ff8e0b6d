"""Tracking a study trial reads only what the study holds: no ground truth of the generator."""

import json
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import json, sys
    from core.study import Study
    from core.tracking.from_study import frame_reader, track_study
    from core.tracking.register import Level, RegistrationOptions
    from core.tracking.trial import TrackingOptions

    with Study.open(sys.argv[1], mode="w") as st:
        read, how = frame_reader(st, st.trial("walk"))
        assert read(0)[0] is not None
        # frame 0 only, one short CMA-ES level: what is imported, not how well it tracks, is the
        # point (the default search took about 5 s of CPU per 64² frame, and both frames were flagged)
        fast = RegistrationOptions(bounds=(5.0, 5.0), refine="pattern", levels=(
            Level(1.0, "cmaes", (1.0, 1.0), popsize=10, max_generations=20, tol_x=0.05),))
        opts = TrackingOptions(registration=fast, first=fast, verify_restarts=0, confidence=False)
        result, report = track_study(st, "walk", ["talus"], [0], options=opts, device="cpu")
    print(json.dumps({"synthetic": sorted(m for m in sys.modules if m.startswith("core.synthetic")),
                      "studies": sorted(m for m in sys.modules if m.startswith("core.studies")),
                      "normalisation": how, "summary": report.get("summary")}))
""")


def test_tracking_a_study_imports_no_synthetic_module(tmp_path):
    from core.synthetic import make_demo_study

    out = tmp_path / "demo"
    make_demo_study(out, n_frames=2, pixels=64, spacing=4.0, tissue_spacing=8.0, device="cpu",
                    calibration_session=False)
    env_py = sys.executable
    done = subprocess.run([env_py, "-c", SCRIPT, str(out)], capture_output=True, text=True, timeout=600,
                          env={"PYTHONWARNINGS": "error", **_env(tmp_path)})
    assert done.returncode == 0, done.stderr[-3000:]
    res = json.loads(done.stdout.strip().splitlines()[-1])
    assert res["synthetic"] == [] and res["studies"] == []
    assert res["summary"] is not None


def _env(tmp_path) -> dict:
    import os

    env = dict(os.environ)
    env.setdefault("XDG_CACHE_HOME", str(tmp_path / "cache"))
    env.setdefault("WARP_CACHE_PATH", str(tmp_path / "warp"))
    return env
