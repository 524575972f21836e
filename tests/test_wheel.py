"""fieldcal installed as a package, not run from the checkout: the sdist and wheel built by
`python -m build`, the wheel installed into a fresh venv, and the commands a newcomer runs first
run from an empty directory outside the checkout (issue 29: an installed fieldcal could not find
its own field-18 procedure nor its sim config).

The fresh venv gets only the wheel (--no-deps); its dependencies (numpy, scipy, textual, ...) are
seen through a .pth line naming the test venv's site-packages, so nothing is downloaded. A .pth
line only adds a path: the test venv's own editable install of fieldcal is not activated there,
and the fieldcal imported is checked to be the wheel's.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

from tests.test_real_recordings import FERRARIS_GRAVITY, FERRARIS_RATE_HZ, REAL

pytestmark = pytest.mark.slow

CHECKOUT = Path(__file__).resolve().parent.parent
# what the build reads: the package sources, the shipped files, the build's own files
SOURCES = ("fieldcal", "drivers", "configs", "procedures", "pyproject.toml", "setup.py", "MANIFEST.in", "README.md")
TIMEOUT_S = 600  # a hung build or command fails the test instead of blocking the run


def _run(argv, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The bin/ of a fresh venv holding the wheel built from a copy of the checkout's sources."""
    source = tmp_path_factory.mktemp("source")
    for name in SOURCES:  # a copy: the build writes build/ and *.egg-info beside what it builds
        copy = shutil.copytree if (CHECKOUT / name).is_dir() else shutil.copy2
        copy(CHECKOUT / name, source / name, **({"ignore": shutil.ignore_patterns("__pycache__")}
                                                if (CHECKOUT / name).is_dir() else {}))
    dist = tmp_path_factory.mktemp("dist")
    # sdist, then the wheel from the unpacked sdist: MANIFEST.in must carry the shipped files too.
    # Without isolation: by the setuptools of this environment (the `test` extra holds the version
    # [build-system] requires; build checks it), not one fetched from the index into a fresh
    # environment for each of the two builds (2.4 s of this fixture's 3.6 s of CPU, and a network)
    built = _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", dist, source], cwd=source)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    (wheel,) = dist.glob("fieldcal-*.whl")

    venv = tmp_path_factory.mktemp("venv") / "venv"
    made = _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=venv.parent)
    assert made.returncode == 0, made.stderr
    python = venv / "bin" / "python"
    added = _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index",
                  "--disable-pip-version-check", "--quiet", wheel], cwd=venv.parent)
    assert added.returncode == 0, added.stderr[-3000:]
    site = _run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=venv.parent)
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(site.stdout.strip()) / "fieldcal-test-dependencies.pth").write_text("\n".join(sorted(ours)) + "\n")
    return venv / "bin"


@pytest.fixture
def elsewhere(tmp_path) -> Path:
    """An empty directory outside the checkout, as a user's."""
    assert not tmp_path.resolve().is_relative_to(CHECKOUT)
    return tmp_path


def test_the_installed_fieldcal_is_the_wheels_with_its_shipped_files(installed, elsewhere):
    probe = ("import fieldcal, fieldcal.paths as p; print(fieldcal.__file__); print(p.SHIPPED_ROOT); "
             "print(*p.shipped_names('procedure')); print(*p.shipped_names('config'))")
    done = _run([installed / "python", "-c", probe], cwd=elsewhere)
    assert done.returncode == 0, done.stderr
    module, root, procedures, configs = done.stdout.splitlines()
    venv = installed.parent.resolve()
    assert Path(module).resolve().is_relative_to(venv)  # not the checkout's editable install
    assert Path(root).resolve() == Path(module).resolve().parent / "_shipped"
    assert procedures.split() == sorted(p.stem for p in (CHECKOUT / "procedures").glob("*.yaml"))
    assert configs.split() == sorted(p.stem for p in (CHECKOUT / "configs").glob("*.yaml"))


def test_the_installed_fieldcal_takes_a_users_file_of_a_shipped_name_first(installed, elsewhere):
    probe = "from fieldcal.config import load_config; print(load_config('sim').device.name)"
    shipped = _run([installed / "python", "-c", probe], cwd=elsewhere)
    assert shipped.returncode == 0, shipped.stderr
    assert shipped.stdout.strip() == "simulated MIMU (paper Tables 3-4)"  # configs/sim.yaml's name
    text = (CHECKOUT / "configs" / "sim.yaml").read_text()
    (elsewhere / "sim.yaml").write_text(text.replace("name: simulated MIMU (paper Tables 3-4)", "name: my bench"))
    own = _run([installed / "python", "-c", probe], cwd=elsewhere)
    assert own.returncode == 0, own.stderr
    assert own.stdout.strip() == "my bench"


def test_fieldcal_demo_runs_from_an_empty_directory(installed, elsewhere):
    done = _run([installed / "fieldcal", "demo", "--seed", "3"], cwd=elsewhere)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    worst = float(re.search(r"largest error: ([0-9.]+)σ", done.stdout).group(1))
    assert worst < 4.0  # against the simulator's known errors (the checkout's test_cli asks the same)


def test_fieldcal_run_of_sim_and_field_18_runs_from_an_empty_directory(installed, elsewhere):
    from fieldcal.paramfile import load

    done = _run([installed / "fieldcal", "run", "--config", "sim", "--procedure", "field-18", "--headless",
                 "--seed", "1"], cwd=elsewhere)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    worst = float(re.search(r"largest error against the simulation truth: ([0-9.]+)σ", done.stdout).group(1))
    assert worst < 4.0
    (params,) = (elsewhere / "sessions").glob("field-18-seed1-*/parameters.yaml")
    assert {"accelerometer", "gyroscope"} <= set(load(params).names)


def test_fieldcal_calibrate_of_a_bundled_recording_from_an_empty_directory(installed, elsewhere):
    """imucal's Ferraris session as it is kept (gzipped), its map found by name; the installed
    fieldcal gives the checkout's calibration of it."""
    from fieldcal.paramfile import load
    from fieldcal.recording.calibrate import UnknownPlace, calibrate_recording
    from fieldcal.recording.importer import import_recording

    recording = shutil.copy2(REAL / "imucal_ferraris_session.csv.gz", elsewhere)
    done = _run([installed / "fieldcal", "calibrate", Path(recording).name, "--map", "imucal", "--rate",
                 FERRARIS_RATE_HZ, "--gravity", FERRARIS_GRAVITY, "--out", "out"], cwd=elsewhere)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "protocol: Ferraris: six axis-aligned poses and full turns" in done.stdout
    (params,) = (elsewhere / "out").glob("*/parameters.yaml")
    ours = calibrate_recording(import_recording([recording], "imucal", rate_hz=FERRARIS_RATE_HZ),
                               UnknownPlace(gravity=FERRARIS_GRAVITY))
    installed_pf = load(params)
    np.testing.assert_allclose(installed_pf["accelerometer"].K, ours.specific_force["accelerometer"].K)
    np.testing.assert_allclose(installed_pf["gyroscope"].K, ours.angular_rate["gyroscope"].K)
