"""Calibration from a plain recording: wall time end to end, and accuracy against the truth.

Speed: a simulated 10-minute, 100 Hz hand-held recording (raw counts, imu_tk's two text files)
is imported, its poses detected (every threshold multiple tried) and both triads solved
(accelerometer by Powell, gyroscope from the rotations), the parameter file built. Median of 5,
in process; then the whole ``fieldcal calibrate`` command on the same two files as its own
process, from start to parameter file (median CPU and wall of 3, peak RSS), and beside it the
peers where installed: imucal (its Ferraris method needs a turntable protocol with hand-marked
regions, so it cannot read this recording: only its import, the floor of any run, is timed).

Accuracy (``--runs N``): N seeded recordings (the default 20 poses); per parameter the RMS of
(solved - true) / reported σ, and the share of |error| beyond 3σ (0.27 % for a Gaussian).

    python benchmarks/recording.py [--runs 100]
"""
from __future__ import annotations

import argparse
import datetime
import os
import sys
import platform
import tempfile
import time
from pathlib import Path

import fieldcal  # noqa: F401  (first: its one-BLAS-thread default applies only before numpy loads)
import numpy as np

from drivers.sim.device import PAPER_NOISE
from drivers.sim.handheld import simulate_handheld, to_text
from fieldcal.earth import Station
from fieldcal.model import params_from_k
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import RecordingSettings, calibrate_recording
from fieldcal.recording.importer import import_with_report
from fieldcal.recording.results import parameter_file

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from processes import BIN, run_once, side_by_side  # noqa: E402

_OFF = (np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1]))
GYRO_NAMES = ("scale x", "scale y", "scale z", "m xy", "m xz", "m yx", "m yz", "m zx", "m zy", "bias x",
              "bias y", "bias z")
ACC_NAMES = ("bias x", "bias y", "bias z", "scale x", "scale y", "scale z", "Δyz", "Δzy", "Δzx")


def speed() -> tuple[float, list[float], int, float, list[str]]:
    sim = simulate_handheld(1, n_poses=34, static_s=(10.0, 20.0))
    station = Station(sim.latitude_deg, 0.0, sim.gravity)
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        files = to_text(sim, tmp)
        for _ in range(5):
            started = time.perf_counter()
            recording, _ = import_with_report(files, "imu_tk")
            cal = calibrate_recording(recording, station)
            parameter_file(cal, recording, station)
            times.append(time.perf_counter() - started)
        lines = processes(files, station, tmp)
    return float(np.median(times)), times, len(cal.poses.intervals), sim.t[-1], lines


def processes(files, station: Station, tmp: str, repeats: int = 3) -> list[str]:
    """The command end to end as a user runs it, and the peers' floor, as table rows."""
    argv = [str(BIN / "fieldcal"), "calibrate", *map(str, files), "--map", "imu_tk",
            "--latitude", f"{station.latitude_deg}", "--gravity", f"{station.gravity}"]
    runs = [run_once(argv + ["--out", os.path.join(tmp, f"out{i}")]) for i in range(repeats)]
    if any(r.status != 0 for r in runs):
        raise SystemExit(f"fieldcal calibrate failed (exit {runs[0].status}): {' '.join(argv)}")
    ours = (float(np.median([r.cpu_s for r in runs])), float(np.median([r.wall_s for r in runs])),
            max(r.peak_mib for r in runs))
    rows = [f"| fieldcal calibrate (process start to parameter file) | {ours[0]:.2f} s | "
            f"{ours[1]:.2f} s | {ours[2]:.0f} MiB | 1.00 |"]
    try:
        import imucal  # noqa: F401  (benchmark only, never a product dependency)
    except ImportError:
        rows.append("| imucal | not installed (pip install imucal) | | | |")
    else:
        peer = [run_once([sys.executable, "-c", "import imucal"]) for _ in range(repeats)]
        cpu = float(np.median([r.cpu_s for r in peer]))
        rows.append(f"| imucal: `import imucal` only (cannot read this recording) | {cpu:.2f} s | "
                    f"{np.median([r.wall_s for r in peer]):.2f} s | {max(r.peak_mib for r in peer):.0f} MiB"
                    f" | {cpu / ours[0]:.2f} (CPU) |")
    return ["| process | CPU (median of 3) | wall | peak RSS | × fieldcal |", "|---|---|---|---|---|", *rows]


def accuracy(runs: int) -> tuple[np.ndarray, np.ndarray]:
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
        z_gyro.append(np.r_[(gyro.theta - np.r_[k, (K / k[:, None] - np.eye(3))[_OFF]]) / gyro.sigma,
                            (gyro.bias - sim.truth["gyroscope"].bias) / cal.gyro_bias_sigma["gyroscope"]])
    return np.array(z_acc), np.array(z_gyro)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=0, help="seeded recordings for the accuracy table")
    args = parser.parse_args()
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}")
    median, times, poses, duration, table = speed()
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load {os.getloadavg()[0]:.1f}")
    print(f"{duration / 60:.1f} min at 100 Hz, {poses} poses: import + detect + solve both triads "
          f"median {median:.2f} s of 5 ({min(times):.2f}-{max(times):.2f} s)")
    print("\n".join(table))
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
    return 0 if median < 1.0 else 1


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
