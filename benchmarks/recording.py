"""Calibration from a plain recording: `fieldcal calibrate` end to end on imu_tk's own Xsens
recording (tests/data/real: 51,175 samples at 100 Hz in two text files, raw counts, 40 static
intervals) beside imu_tk itself, and accuracy against the simulator's truth.

Speed: each tool is its own process, timed from process start to parameter file; CPU seconds
(user + system) and peak resident memory come from ``os.wait4`` (the child's own
``getrusage``). Every round runs each process once, in turn (a change of the machine's load hits
all of them alike), after one run of each that caches the bytecode (as an installed package has
it); medians of ``--repeats`` rounds, the peak RSS the largest. Beside them: imu_tk (C++, Ceres,
built by ``benchmarks/peers/build_imu_tk.sh``, skipped with a line when not built), the floor
any Python calibration with Powell pays (``FLOOR``: numpy and scipy.optimize, imported as
`fieldcal calibrate` imports them), and ``import imucal`` (imucal cannot read this recording);
with ``--baseline REV``, fieldcal as of that git revision beside this tree's, both launched
alike (the change's own effect). Printed: each one's CPU, wall and peak RSS, its ratio to
imu_tk's, the date and the load average; then both tools' results side by side.

Accuracy (``--runs N``): N seeded simulated recordings (the default 20 poses); per parameter the
RMS of (solved - true) / reported σ, and the share of |error| beyond 3σ (0.27 % for a Gaussian).

    python benchmarks/recording.py [--repeats 7] [--runs 100] [--baseline bcecd58]
    python benchmarks/recording.py --joined --repeats 3   # the 1×/4×/16× joined recordings' scaling
"""
from __future__ import annotations

import argparse
import datetime
import gzip
import importlib.util
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import fieldcal  # noqa: F401  (first: its one-BLAS-thread default applies only before numpy loads)
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from processes import BIN, run_once, side_by_side  # noqa: E402

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


def joined_xsens(directory: Path, copies: int) -> list[Path]:
    """imu_tk's two Xsens files joined to themselves ``copies`` times into ``directory``: forward
    and time-reversed copies in turn, so each join is physically continuous (a reversed copy
    starts where the one before ended). Time runs on at the recording's own steps; a
    reversed copy's gyro turns the other way about its bias (the first second's mean, at rest):
    2b − u. The accelerometer reads the same forces backwards."""
    acc, gyro = (np.loadtxt(REAL / name) for name in XSENS)
    t = acc[:, 0]
    steps = np.diff(t, append=t[-1] + np.median(np.diff(t)))
    bias = gyro[t < t[0] + 1.0, 1:].mean(axis=0)
    reversed_gyro = np.column_stack([t, 2 * bias - gyro[::-1, 1:]])
    parts_acc, parts_gyro = [], []
    for copy in range(copies):
        forward = copy % 2 == 0
        parts_acc.append((acc if forward else acc[::-1])[:, 1:])
        parts_gyro.append(gyro[:, 1:] if forward else reversed_gyro[:, 1:])
    times = t[0] + np.r_[0.0, np.cumsum(np.tile(np.r_[steps, steps[::-1]], copies)[:copies * len(t) - 1])]
    paths = [directory / f"joined{copies}_acc.txt", directory / f"joined{copies}_gyro.txt"]
    for path, parts in zip(paths, (parts_acc, parts_gyro)):
        np.savetxt(path, np.column_stack([times, np.vstack(parts)]), fmt=["%.6f", "%d", "%d", "%d"])
    return paths


IMU_TK_OUT = Path(__file__).parent / "out" / "imu_tk"  # benchmarks/peers/build_imu_tk.sh builds here
# What every `fieldcal calibrate` imports before its own modules, imported as it imports them:
# numpy and scipy.optimize (the accelerometer's Powell search; scipy.optimize's __init__ loads
# every solver, scipy.linalg, scipy.special and scipy.spatial with it), after fieldcal's
# one-BLAS-thread default (fieldcal/__init__.py), with the cyclic collector paused and what they
# made frozen (cli.startup.imports_uncollected), so that the collection at exit skips it too.
# A bare `python -c 'import numpy, scipy.optimize'` costs 1.4× that (0.572 against 0.398 s CPU,
# medians of 11 alternating runs, 2026-11-28 00:52 UTC, load 16): OpenBLAS's threads, the
# collections during the import and ~0.1 s of collection at exit that calibrate does not pay;
# as the floor it understated calibrate's own CPU (CPU − floor) by ~0.17 s.
FLOOR_IMPORTS = ("from fieldcal.cli.startup import imports_uncollected\n"
                 "with imports_uncollected():\n    import numpy, scipy.optimize")
FLOOR = "python -c 'import numpy, scipy.optimize' as calibrate imports them"


def commands(files: list[Path], work: Path) -> dict[str, list[str]]:
    """The processes timed side by side, by label; imu_tk and imucal only where they are present."""
    params = work / "fieldcal.yaml"
    # Where the recording was made is not published: --gravity alone, as a new user would. The
    # registry is a scratch one (the command records every parameter file it writes).
    out = {"fieldcal calibrate": [
        str(BIN / "fieldcal"), "calibrate", *map(str, files), "--map", "imu_tk", "--gravity", f"{XSENS_GRAVITY}",
        "--params", str(params), "--force", "--out", str(work / "sessions"),
        "--registry", str(work / "registry.sqlite")]}
    if (IMU_TK_OUT / "imu_tk_calib").exists():
        out["imu_tk (C++, Ceres)"] = [str(IMU_TK_OUT / "imu_tk_calib"), *map(str, files), str(work / "imu_tk")]
    out[FLOOR] = [sys.executable, "-c", FLOOR_IMPORTS]
    if importlib.util.find_spec("imucal") is not None:  # benchmark only, never a product dependency
        out["python -c 'import imucal' (cannot read this recording)"] = [sys.executable, "-c", "import imucal"]
    return out


def speed_table(rows, reference: str | None) -> list[str]:
    """Markdown rows: each process's medians and its ratio to ``reference`` (imu_tk)."""
    ref = next((r for r in rows if r.label == reference), None)
    lines = ["| process | CPU | wall | peak RSS | CPU ÷ imu_tk | RSS ÷ imu_tk |", "|---|---|---|---|---|---|"]
    for r in rows:
        ratios = (f"{r.cpu_s / ref.cpu_s:.2f}× | {r.peak_mib / ref.peak_mib:.2f}×" if ref is not None else "— | —")
        lines.append(f"| {r.label} | {r.cpu_s:.3f} s | {r.wall_s:.2f} s | {r.peak_mib:.0f} MiB | {ratios} |")
    return lines


# As the `fieldcal` script does: its entry point (run, which reads sys.argv) where the tree has one.
_LAUNCH = ("import sys; sys.path[:0] = {path!r}; import fieldcal.cli.main as m; sys.argv = ['fieldcal', *{argv!r}]; "
           "raise SystemExit(m.run() if hasattr(m, 'run') else m.main(sys.argv[1:]))")


def with_baseline(argv: dict[str, list[str]], rev: str, work: Path) -> dict[str, list[str]]:
    """``argv`` and fieldcal calibrate as of git revision ``rev`` (``git archive`` into ``work``),
    each run the same way (``python -c``, the tree first on the path, its own parameter file and
    registry), so that old and new alternate in one series and their difference is the change."""
    root = Path(__file__).resolve().parent.parent
    tree = work / "baseline"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(root), "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    ours = argv["fieldcal calibrate"][1:]
    out = dict(argv)
    for label, path, name in ((f"fieldcal calibrate as of {rev}", [str(tree)], "baseline"),
                              ("fieldcal calibrate (this tree, launched as the baseline)", [], "this")):
        own = {work / "fieldcal.yaml": work / f"{name}.yaml", work / "registry.sqlite": work / f"{name}.sqlite",
               work / "sessions": work / f"{name}-sessions"}  # a session's name has the second it began
        args = [str(own.get(Path(a), a)) for a in ours]
        out[label] = [sys.executable, "-c", _LAUNCH.format(path=path, argv=args)]
    return out


def speed(repeats: int, baseline: str | None = None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        argv = commands(xsens_files(work), work)  # imu_tk's text format, which fieldcal reads by its map
        if baseline:
            argv = with_baseline(argv, baseline, work)
        for label, command in argv.items():  # bytecode cached, files in the page cache
            if run_once(command).status != 0:
                raise SystemExit(f"{label} failed: {' '.join(command)}")
        rows = side_by_side(argv, repeats)
        if any(r.status != 0 for r in rows):
            raise SystemExit(f"a run failed ({', '.join(f'{r.label}: exit {r.status}' for r in rows)})")
        compared = (_against_imu_tk(str(work / "fieldcal.yaml"), str(work / "imu_tk"))
                    if "imu_tk (C++, Ceres)" in argv else [])
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load "
          f"{os.getloadavg()[0]:.1f} (1 min): imu_tk's Xsens recording (51,175 samples × 2 triads, two "
          f"text files), process start to parameter file, medians of {repeats} alternating rounds")
    print("\n".join(speed_table(rows, "imu_tk (C++, Ceres)")))
    ours = next(r for r in rows if r.label == "fieldcal calibrate")
    peer = next((r for r in rows if r.label == "imu_tk (C++, Ceres)"), None)
    if peer is None:
        print("imu_tk: not built (benchmarks/peers/build_imu_tk.sh builds it into benchmarks/out/imu_tk)")
    else:
        print(f"fieldcal ÷ imu_tk: CPU {ours.cpu_s / peer.cpu_s:.2f}× ({ours.cpu_s:.2f} s ÷ {peer.cpu_s:.2f} s), "
              f"peak RSS {ours.peak_mib / peer.peak_mib:.2f}× ({ours.peak_mib:.0f} ÷ {peer.peak_mib:.0f} MiB)")
        print("\n".join(compared))


JOINS = (1, 4, 16)


def scaling(repeats: int) -> None:
    """`fieldcal calibrate` (and imu_tk, where built) on imu_tk's recording joined to itself
    1×/4×/16× (``joined_xsens``): CPU, the CPU less the import floor, and that work's growth
    against the recording's (1.00× is linear)."""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        argv: dict[str, list[str]] = {FLOOR: [sys.executable, "-c", FLOOR_IMPORTS]}
        for copies in JOINS:
            files = joined_xsens(work, copies)
            argv[f"fieldcal calibrate {copies}×"] = [
                str(BIN / "fieldcal"), "calibrate", *map(str, files), "--map", "imu_tk", "--gravity",
                f"{XSENS_GRAVITY}", "--out", str(work / f"sessions{copies}"), "--registry",
                str(work / f"registry{copies}.sqlite")]
            if (IMU_TK_OUT / "imu_tk_calib").exists():
                argv[f"imu_tk {copies}×"] = [str(IMU_TK_OUT / "imu_tk_calib"), *map(str, files),
                                            str(work / f"imu_tk{copies}")]
        for label, command in argv.items():
            if run_once(command).status != 0:
                raise SystemExit(f"{label} failed: {' '.join(command)}")
        rows = {r.label: r for r in side_by_side(argv, repeats)}
    floor = rows[FLOOR].cpu_s
    print(f"\n{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load {os.getloadavg()[0]:.1f} "
          f"(1 min): imu_tk's recording joined to itself (forward and time-reversed copies), medians of "
          f"{repeats} alternating rounds; import floor {floor:.3f} s CPU")
    print("| process | CPU | CPU − floor | growth ÷ recording's | peak RSS |\n|---|---|---|---|---|")
    for tool in ("fieldcal calibrate", "imu_tk"):
        first = rows.get(f"{tool} 1×")
        for copies in JOINS:
            r = rows.get(f"{tool} {copies}×")
            if r is None:
                continue
            own = r.cpu_s - floor if tool != "imu_tk" else r.cpu_s
            base = first.cpu_s - floor if tool != "imu_tk" else first.cpu_s
            print(f"| {r.label} | {r.cpu_s:.2f} s | {own:.2f} s | {own / base / copies:.2f}× | {r.peak_mib:.0f} MiB |")
    if "imu_tk 1×" in rows:
        print("\n".join(joined_side_by_side(rows)))


def joined_side_by_side(rows) -> list[str]:
    """Markdown rows: at each join, fieldcal's and imu_tk's medians from the same rounds and
    their ratios (process CPU and peak RSS, the import floor included, as each user pays it)."""
    lines = ["| join | fieldcal CPU | imu_tk CPU | CPU ÷ imu_tk | fieldcal peak RSS | imu_tk peak RSS | RSS ÷ imu_tk |",
             "|---|---|---|---|---|---|---|"]
    for copies in JOINS:
        ours, peer = rows[f"fieldcal calibrate {copies}×"], rows[f"imu_tk {copies}×"]
        lines.append(f"| {copies}× | {ours.cpu_s:.2f} s | {peer.cpu_s:.2f} s | {ours.cpu_s / peer.cpu_s:.2f}× | "
                     f"{ours.peak_mib:.0f} MiB | {peer.peak_mib:.0f} MiB | {ours.peak_mib / peer.peak_mib:.3f}× |")
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
    parser.add_argument("--repeats", type=int, default=7, help="rounds of the processes (medians)")
    parser.add_argument("--runs", type=int, default=0, help="seeded recordings for the accuracy table")
    parser.add_argument("--baseline", metavar="REV", help="also time fieldcal calibrate as of this git "
                        "revision, alternating with this tree's (e.g. the commit a change started from)")
    parser.add_argument("--joined", action="store_true", help="only the 1×/4×/16× joined recordings' "
                        "scaling (see scaling)")
    args = parser.parse_args()
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # the children cache their bytecode, as installed
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}")
    if args.joined:
        scaling(args.repeats)
        return 0
    speed(args.repeats, args.baseline)
    if args.runs:
        started = time.perf_counter()
        z_acc, z_gyro = accuracy(args.runs)
        print(f"accuracy over {args.runs} recordings ({time.perf_counter() - started:.0f} s): "
              "RMS of error/σ, share beyond 3σ")
        for triad, names, z in (("accelerometer", ACC_NAMES, z_acc), ("gyroscope", GYRO_NAMES, z_gyro)):
            rms = np.sqrt(np.mean(z**2, axis=0))
            print(f"  {triad}: " + ", ".join(f"{n} {r:.2f}" for n, r in zip(names, rms))
                  + f"; beyond 3σ {100 * np.mean(np.abs(z) > 3):.2f} %")
    return 0


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
