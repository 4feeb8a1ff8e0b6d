"""The one-way dependency ``app -> core`` is enforced, and ``core`` runs without Qt or a display."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GUI_MODULES = ("PySide6", "shiboken6", "pyvistaqt", "pyvista", "vtk", "vtkmodules", "superqt",
               "psygnal", "app")


def _lint_imports_command() -> list[str]:
    script = Path(sys.executable).with_name("lint-imports")
    if script.exists():
        return [str(script)]
    found = shutil.which("lint-imports")
    if found:
        return [found]
    return [sys.executable, "-c", "from importlinter.cli import lint_imports_command as c; c()"]


def _env_without_display() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["QT_QPA_PLATFORM"] = "minimal"  # would be used only if something tried to start Qt
    return env


def test_import_contracts_hold():
    # lint-imports prints box-drawing characters: decode as UTF-8 whatever the locale (CI: C)
    env = {**os.environ, "PYTHONIOENCODING": "utf-8", "PYTHONUTF8": "1"}
    done = subprocess.run(
        _lint_imports_command(), capture_output=True, text=True, encoding="utf-8",
        errors="replace", cwd=ROOT, timeout=300, env=env,
    )
    assert done.returncode == 0, f"lint-imports failed:\n{done.stdout}\n{done.stderr}"


def test_every_core_module_imports_without_qt_or_display():
    code = textwrap.dedent(
        f"""
        import importlib, pkgutil, sys, traceback
        for name in {GUI_MODULES!r}:
            sys.modules[name] = None  # any import of these raises ImportError
        import core
        names = ["core"]
        failures = []
        def onerror(name):
            failures.append((name, traceback.format_exc()))
        names += [m.name for m in pkgutil.walk_packages(core.__path__, "core.", onerror)]
        for name in names:
            try:
                importlib.import_module(name)
            except Exception:
                failures.append((name, traceback.format_exc()))
        for name, tb in failures:
            print("FAILED", name, tb, sep="\\n")
        print("imported", len(names) - len(failures), "of", len(names))
        sys.exit(1 if failures else 0)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True, text=True, cwd=ROOT, timeout=300, env=_env_without_display(),
    )
    assert done.returncode == 0, f"{done.stdout}\n{done.stderr}"
    assert "imported" in done.stdout


def test_contracts_cover_every_library_package():
    """A new package of ``core`` is a library package, and so is bound by the contracts that keep
    the evaluation (``core.studies``) and the generator (``core.synthetic``) out of the library,
    unless it is one of those two."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = {c["name"]: c for c in config["tool"]["importlinter"]["contracts"]}
    packages = {f"core.{p.name}" for p in (ROOT / "core").iterdir()
                if (p / "__init__.py").is_file()} - {"core.studies", "core.synthetic"}
    assert packages, "no package found under core/"
    for forbidden in ("core.studies", "core.synthetic"):
        found = [c for c in contracts.values() if c.get("forbidden_modules") == [forbidden]]
        assert len(found) == 1, f"pyproject.toml: expected one contract forbidding {forbidden}"
        missing = packages - set(found[0]["source_modules"])
        assert not missing, f"pyproject.toml: {found[0]['name']!r} does not list {sorted(missing)}"
