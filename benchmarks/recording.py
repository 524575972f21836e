"""Calibration from a plain recording: `fieldcal calibrate` end to end on imu_tk's own Xsens
recording (tests/data/real: 51,175 samples at 100 Hz in two text files, raw counts, 38 poses),
and accuracy against the simulator's truth.

Speed: each tool is its own process, timed from process start to parameter file; CPU seconds
(user + system) and peak resident memory come from ``os.wait4`` (the child's own
``getrusage``), medians of ``--repeats`` runs, after one run that caches the bytecode (as an
installed package has it). One function per measured tool: ``fieldcal_calibrate`` and the peers beside it.

Accuracy (``--runs N``): N seeded simulated recordings (the default 20 poses); per parameter the
RMS of (solved - true) / reported σ, and the share of |error| beyond 3σ (0.27 % for a Gaussian).

    python benchmarks/recording.py [--repeats 5] [--runs 100]
"""
from __future__ import annotations

import argparse
import datetime
import gzip
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import fieldcal  # noqa: F401  (first: its one-BLAS-thread default applies only before numpy loads)
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from processes import BIN, Run, run_once, side_by_side  # noqa: E402

REAL = Path(__file__).resolve().parent.parent / "tests" / "data" / "real"
XSENS = ("imu_tk_xsens_acc.mat.gz", "imu_tk_xsens_gyro.mat.gz")
XSENS_GRAVITY = 9.81744  # m/s^2, what imu_tk's example uses for this recording (as tests/test_real_recordings.py)
_OFF = (np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1]))
GYRO_NAMES = ("scale x", "scale y", "scale z", "m xy", "m xz", "m yx", "m yz", "m zx", "m zy", "bias x",
              "bias y", "bias z")
ACC_NAMES = ("bias x", "bias y", "bias z", "scale x", "scale y", "scale z", "Δyz", "Δzy", "Δzx")


def xsens_files(directory: Path) -> list[Path]:
    """imu_tk's two Xsens files, unpacked into ``directory``."""
    paths = [directory / name.removesuffix(".gz") for name in XSENS]
    for name, path in zip(XSENS, paths):
        path.write_bytes(gzip.decompress((REAL / name).read_bytes()))
    return paths


def _summary(label: str, runs: list[Run]) -> tuple[str, float, float, float]:
    if any(r.status != 0 for r in runs):
        raise SystemExit(f"{label} failed (exit {runs[0].status})")
    return (label, statistics.median(r.cpu_s for r in runs), statistics.median(r.wall_s for r in runs),
            max(r.peak_mib for r in runs))


def fieldcal_calibrate(files: list[Path], work: Path, repeats: int) -> tuple[str, float, float, float]:
    """(label, median CPU s, median wall s, peak MiB) of the whole command, parameter file written."""
    def argv(i):
        return [str(BIN / "fieldcal"), "calibrate", *map(str, files), "--map", "imu_tk", "--latitude", "45",
                "--gravity", str(XSENS_GRAVITY), "--out", str(work / f"out{i}"),
                "--registry", str(work / "registry.sqlite")]
    run_once(argv("-warm-up"))  # writes the bytecode caches
    return _summary("fieldcal calibrate", [run_once(argv(i)) for i in range(repeats)])


def imucal_import(repeats: int) -> tuple[str, float, float, float] | str:
    """imucal cannot read this recording (its Ferraris method needs hand-marked turntable
    regions): only `import imucal`, the floor of any run of it."""
    try:
        import imucal  # noqa: F401  (benchmark only, never a product dependency)
    except ImportError:
        return "imucal: not installed (pip install imucal)"
    runs = [run_once([sys.executable, "-c", "import imucal"]) for _ in range(repeats)]
    return _summary("imucal: `import imucal` only (cannot read this recording)", runs)


def table(rows: list) -> list[str]:
    ours = rows[0]
    lines = ["| process | CPU (median) | wall (median) | peak RSS | CPU × fieldcal |", "|---|---|---|---|---|"]
    for row in rows:
        if isinstance(row, str):
            lines.append(f"| {row} | | | | |")
        else:
            label, cpu, wall, peak = row
            lines.append(f"| {label} | {cpu:.2f} s | {wall:.2f} s | {peak:.0f} MiB | {cpu / ours[1]:.2f} |")
    return lines


def accuracy(runs: int) -> tuple[np.ndarray, np.ndarray]:
    from drivers.sim.device import PAPER_NOISE
    from drivers.sim.handheld import simulate_handheld
    from fieldcal.earth import Station
    from fieldcal.model import params_from_k
    from fieldcal.recording import Recording
    from fieldcal.recording.calibrate import RecordingSettings, calibrate_recording

    z_acc, z_gyro = [], []
    for seed in range(1, runs + 1):
        sim = simulate_handheld(seed)
        cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                                  Station(sim.latitude_deg, 0.0, sim.gravity),
                                  RecordingSettings(noise=dict(PAPER_NOISE)))
        acc, truth = cal.specific_force["accelerometer"], sim.truth["accelerometer"]
        z_acc.append((acc.theta - params_from_k(truth.K, truth.bias)) / acc.sigma)
        gyro, K = cal.angular_rate["gyroscope"], sim.truth["gyroscope"].K
        k = np.diag(K)
        z_gyro.append(np.r_[(gyro.theta[3:] - np.r_[k, (K / k[:, None] - np.eye(3))[_OFF]]) / gyro.sigma[3:],
                            (gyro.bias - sim.truth["gyroscope"].bias) / cal.gyro_bias_sigma["gyroscope"]])
    return np.array(z_acc), np.array(z_gyro)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs of each process (medians)")
    parser.add_argument("--runs", type=int, default=0, help="seeded recordings for the accuracy table")
    args = parser.parse_args()
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # the children cache their bytecode, as installed
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}")
    with tempfile.TemporaryDirectory() as tmp:
        files = xsens_files(Path(tmp))
        rows = [fieldcal_calibrate(files, Path(tmp), args.repeats), imucal_import(args.repeats)]
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load {os.getloadavg()[0]:.1f}: "
          f"imu_tk's Xsens recording (two files, 51,175 samples), process start to parameter file")
    print("\n".join(table(rows)))
    if args.runs:
        started = time.perf_counter()
        z_acc, z_gyro = accuracy(args.runs)
        print(f"accuracy over {args.runs} recordings ({time.perf_counter() - started:.0f} s): "
              "RMS of error/σ, share beyond 3σ")
        for triad, names, z in (("accelerometer", ACC_NAMES, z_acc), ("gyroscope", GYRO_NAMES, z_gyro)):
            rms = np.sqrt(np.mean(z**2, axis=0))
            print(f"  {triad}: " + ", ".join(f"{n} {r:.2f}" for n, r in zip(names, rms))
                  + f"; beyond 3σ {100 * np.mean(np.abs(z) > 3):.2f} %")
    imu_tk_peer()
    return 0


IMU_TK_OUT = Path(__file__).parent / "out" / "imu_tk"  # benchmarks/peers/build_imu_tk.sh builds here
IMU_TK_GRAVITY = 9.81744  # m/s^2, what imu_tk's example app uses for its Xsens recording


def imu_tk_peer(repeats: int = 3) -> None:
    """imu_tk (C++, Ceres) beside ``fieldcal calibrate`` on imu_tk's own Xsens files, each as its
    own process, alternating in every round (a load change hits both alike): CPU, wall and peak
    RSS of the child, the ratio fieldcal/imu_tk, and both results' biases and scale factors (imu_tk's
    in fieldcal's convention: counts per m/s² or per rad/s) with fieldcal's σ. Skipped with a line
    when imu_tk is not built (``benchmarks/peers/build_imu_tk.sh``)."""
    import gzip

    binary = IMU_TK_OUT / "imu_tk_calib"
    if not binary.exists():
        print("imu_tk: not built (benchmarks/peers/build_imu_tk.sh builds it into benchmarks/out/imu_tk)")
        return
    real = Path(__file__).parent.parent / "tests" / "data" / "real"
    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for triad in ("acc", "gyro"):  # imu_tk's own text format, as the build script unpacks it
            files.append(Path(tmp) / f"xsens_{triad}.mat")
            files[-1].write_bytes(gzip.decompress((real / f"imu_tk_xsens_{triad}.mat.gz").read_bytes()))
        # Where the recording was made is not published: --gravity alone, as a new user would.
        ours = [str(BIN / "fieldcal"), "calibrate", *map(str, files), "--map", "imu_tk",
                "--gravity", f"{IMU_TK_GRAVITY}", "--params", os.path.join(tmp, "fieldcal.yaml"), "--force",
                "--out", os.path.join(tmp, "sessions")]
        peer = [str(binary), *map(str, files), os.path.join(tmp, "imu_tk")]
        rows = side_by_side({"fieldcal calibrate": ours, "imu_tk (C++, Ceres)": peer}, repeats)
        if any(r.status != 0 for r in rows):
            raise SystemExit(f"imu_tk peer: a run failed ({', '.join(f'{r.label}: exit {r.status}' for r in rows)})")
        compared = _against_imu_tk(os.path.join(tmp, "fieldcal.yaml"), os.path.join(tmp, "imu_tk"))
    fieldcal_run, imu_tk_run = rows
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load {os.getloadavg()[0]:.1f}: "
          f"imu_tk's Xsens recording (51,175 samples × 2 triads), median of {repeats}, side by side")
    print("| process | CPU | wall | peak RSS |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r.label} | {r.cpu_s:.2f} s | {r.wall_s:.2f} s | {r.peak_mib:.0f} MiB |")
    print(f"fieldcal / imu_tk: CPU {fieldcal_run.cpu_s / imu_tk_run.cpu_s:.2f}×, wall "
          f"{fieldcal_run.wall_s / imu_tk_run.wall_s:.2f}×, peak RSS {fieldcal_run.peak_mib / imu_tk_run.peak_mib:.2f}×")
    print("\n".join(compared))


def _against_imu_tk(params_path: str, imu_tk_prefix: str) -> list[str]:
    """fieldcal's and imu_tk's results on the same files, in what does not depend on how each
    defines its axes: the biases, each axis's sensitivity (the norm of its row of K, counts per
    m/s² or rad/s; fieldcal's σ of the scale factor beside it, the off-diagonal terms being small)
    and the angles between the sensitive axes."""
    from fieldcal.paramfile import load

    ours = load(params_path)
    lines = ["| triad | quantity | fieldcal ± 1σ | imu_tk | imu_tk − fieldcal |", "|---|---|---|---|---|"]
    for triad, suffix in (("accelerometer", "acc"), ("gyroscope", "gyro")):
        values = np.array(Path(f"{imu_tk_prefix}_{suffix}.calib").read_text().split(), dtype=float)
        # imu_tk: calibrated = T·S·(raw − b); fieldcal: raw = K·true + b, so imu_tk's K = (T·S)⁻¹.
        k_peer = np.linalg.inv(values[:9].reshape(3, 3) @ values[9:18].reshape(3, 3))
        mine = ours[triad]
        names = mine.parameter_names
        for axis, b_peer, i in zip("xyz", values[18:21], (names.index(f"bias_{a}") for a in "xyz")):
            lines.append(f"| {triad} | bias {axis}, {mine.output_unit} | {mine.theta[i]:.6g} ± {mine.sigma[i]:.2g} | "
                         f"{b_peer:.6g} | {(b_peer - mine.theta[i]) / mine.sigma[i]:+.1f} σ |")
        for axis, k_mine, k_theirs, i in zip("xyz", np.linalg.norm(mine.K, axis=1), np.linalg.norm(k_peer, axis=1),
                                             (names.index(f"scale_{a}") for a in "xyz")):
            lines.append(f"| {triad} | sensitivity {axis}, {mine.output_unit} per {mine.input_unit} | {k_mine:.6g} ± "
                         f"{mine.sigma[i]:.2g} | {k_theirs:.6g} | {(k_theirs - k_mine) / mine.sigma[i]:+.1f} σ |")
        for pair, a_mine, a_theirs in zip(("x∠y", "x∠z", "y∠z"), _axis_angles(mine.K), _axis_angles(k_peer)):
            lines.append(f"| {triad} | angle {pair} | {a_mine:.4f}° | {a_theirs:.4f}° | {a_theirs - a_mine:+.4f}° |")
    return lines


def _axis_angles(K: np.ndarray) -> np.ndarray:
    """Angles (°) between the rows of K (the sensitive axes), x∠y, x∠z, y∠z."""
    unit = K / np.linalg.norm(K, axis=1)[:, None]
    return np.degrees(np.arccos(np.clip([unit[0] @ unit[1], unit[0] @ unit[2], unit[1] @ unit[2]], -1, 1)))


if __name__ == "__main__":
    raise SystemExit(main())
