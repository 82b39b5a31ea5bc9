"""A non-editable install carries its defaults: configs/*.toml and configs/recipes/*.toml go into the wheel as the
package data rfir_core._configs, and an installed wheel runs from a folder outside the repository.

The wheel is built from a copy of the project (so the repository gets no build/ folder) with
`pip wheel --no-deps --no-build-isolation --no-index`: offline, against the torch already installed.
The fast check builds it without the extension (RFIR_NO_EXT=1, seconds) and reads its file list. The slow
check builds the real wheel once per module (the extension compiles: 2 to 6 min of wall time on 2 shared
cores, measured 115 s to 330 s), installs it into a fresh venv that borrows this environment's packages (torch included) through a
.pth file, and runs `rfir --help`, `rfir mesh-gaussians`, `rfir rf-fit` and `rfir predict rssi` on the
reduced room of tests/rssi/helpers.py, from a temporary folder.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ("pyproject.toml", "setup.py", "README.md", "src", "stages", "ext", "configs")
LEFT_OUT = shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.o", "build", "*.egg-info")


def build_wheel(work: Path, extension: bool) -> Path:
    """Copy the project under work/ and build its wheel there; returns the wheel's path."""
    src = work / "project"
    src.mkdir(parents=True)
    for name in PROJECT:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=LEFT_OUT)
        else:
            shutil.copy2(ROOT / name, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("RFIR_NO_EXT", "PIP_REQUIRE_VIRTUALENV")}
    if not extension:
        env["RFIR_NO_EXT"] = "1"
    out = work / "wheels"
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index",
           str(src), "-w", str(out)]
    run = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    (wheel,) = out.glob("rfir-*.whl")
    return wheel


def test_the_wheel_carries_every_default_config_and_module(tmp_path):
    wheel = build_wheel(tmp_path, extension=False)
    names = set(zipfile.ZipFile(wheel).namelist())
    configs = sorted((ROOT / "configs").glob("*.toml"))
    recipes = sorted((ROOT / "configs" / "recipes").glob("*.toml"))
    assert len(configs) >= 5 and recipes, "configs/ holds almost nothing: is ROOT right?"
    missing = [p.name for p in configs if f"rfir_core/_configs/{p.name}" not in names]
    missing += [f"recipes/{p.name}" for p in recipes if f"rfir_core/_configs/recipes/{p.name}" not in names]
    assert not missing, f"the wheel lacks these configs/ files (rfir_core/_configs): {missing}"
    for package, folder in (("rfir_core", ROOT / "src" / "rfir_core"), ("rfir_cli", ROOT / "src" / "rfir_cli"), ("rfir_stages", ROOT / "stages"),
                            ("rfir_tracer", ROOT / "ext" / "rfir_tracer")):
        modules = [f"{package}/{p.relative_to(folder).as_posix()}" for p in folder.rglob("*.py")
                   if "__pycache__" not in p.parts]
        lost = sorted(m for m in modules if m not in names)
        assert not lost, f"the wheel lacks these modules (setup.py's _packages()): {lost[:10]}"
    assert "rfir_cli/py.typed" in names
    (entry,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    assert "rfir = rfir_cli.main:main" in zipfile.ZipFile(wheel).read(entry).decode()


# ------------------------------------------------------------------------------------------------------------------
# the installed wheel, run from outside the repository (slow: the wheel compiles the extension)
# ------------------------------------------------------------------------------------------------------------------
def _site_dirs() -> list[str]:
    paths = sysconfig.get_paths()
    return list(dict.fromkeys([paths["purelib"], paths["platlib"]]))


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv folder, environment for its commands, a working folder outside the repository, timings [s])."""
    work = tmp_path_factory.mktemp("wheel")
    t0 = time.perf_counter()
    wheel = build_wheel(work, extension=True)
    t1 = time.perf_counter()
    venv = work / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    # this environment's packages (torch, numpy, pip, ...) after the venv's own: nothing is downloaded
    (Path(site) / "_rfir_test_borrowed.pth").write_text("\n".join(_site_dirs()) + "\n")
    env = {k: v for k, v in os.environ.items() if k not in ("RFIR_CONFIG_DIR", "PYTHONPATH", "PYTHONHOME",
                                                            "VIRTUAL_ENV", "PIP_REQUIRE_VIRTUALENV")}
    env.update(OMP_NUM_THREADS="1", PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}")
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--ignore-installed",
                    str(wheel)], check=True,
                   env=env, timeout=600)
    outside = work / "outside"
    outside.mkdir()
    timings = {"build_s": t1 - t0, "install_s": time.perf_counter() - t1}
    print(f"\nwheel with the extension built in {timings['build_s']:.0f} s, installed in {timings['install_s']:.0f} s")
    return venv, env, outside, timings


def _rfir(installed, *args, timeout=900):
    venv, env, outside, _ = installed
    run = subprocess.run([str(venv / "bin" / "rfir"), *map(str, args)], cwd=outside, env=env, capture_output=True,
                         text=True, timeout=timeout)
    assert run.returncode == 0, f"rfir {' '.join(map(str, args))}:\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    return run.stdout


@pytest.mark.slow
def test_the_installed_wheel_reads_its_defaults_from_the_package(installed):
    venv, env, outside, _ = installed
    probe = ("import json, rfir_core.config as c, rfir_tracer._ext as e; "
             "print(json.dumps([c.__file__, str(c.config_dir()), sorted(c.load_defaults()), e.native().__file__]))")
    run = subprocess.run([str(venv / "bin" / "python"), "-c", probe], cwd=outside, env=env, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    module, folder, sections, extension = json.loads(run.stdout.splitlines()[-1])
    for path in (module, folder, extension):
        assert Path(path).resolve().is_relative_to(venv.resolve()), f"{path} is not the installed wheel's"
    assert Path(folder).name == "_configs"
    assert {"general", "rf_fit", "predict"} <= set(sections)
    assert "mesh-gaussians" in _rfir(installed, "--help")


@pytest.mark.slow
def test_the_installed_wheel_fits_and_predicts_a_small_room(installed):
    from ..rssi.helpers import room_mesh, write_measurements

    _, _, outside, _ = installed
    v, f, labels, names = room_mesh()
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
    for label, name in enumerate(names):
        lines.append(f"o {name}")
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f[labels == label]]
    (outside / "room.obj").write_text("\n".join(lines) + "\n")
    write_measurements(outside / "meas.h5")
    t0 = time.perf_counter()
    _rfir(installed, "mesh-gaussians", "room.obj", "-o", "scene.h5", "--preset", "room", "--spacing", "0.6")
    _rfir(installed, "--set", "rf_fit.physical.iterations=20", "--set", "rf_fit.physical.start_iterations=5",
          "rf-fit", "scene.h5", "meas.h5", "-o", "rf.h5")
    _rfir(installed, "predict", "rssi", "rf.h5", "--measurements", "meas.h5", "-o", "p.h5", "--results", "r.json")
    print(f"\nmesh-gaussians + rf-fit + predict rssi from the installed wheel: {time.perf_counter() - t0:.0f} s")
    metrics = json.loads((outside / "r.json").read_text())["metrics"]
    assert metrics["num_test"] > 0 and math.isfinite(metrics["mae_db"])
    assert (outside / "p.h5").is_file() and (outside / "rf.h5").is_file()
