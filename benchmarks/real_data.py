"""fieldcal on the public real recordings in tests/data/real: the README's real-data table.

Per recording: the poses found, the accelerometer's fit (RMS of |a| − g per sample and per
interval mean, on fieldcal's own intervals, and on the intervals it shares with the peer tool
where the peer's are published or reproduced; imu_tk's recorded result on the same intervals), the main parameters ± 1σ, and the source's or peer's result
on the same data where one exists (imucal is run on its own session when installed).

    python benchmarks/real_data.py
"""
from __future__ import annotations

import datetime
import gzip
import json
import sys
import tempfile
from pathlib import Path

import fieldcal  # noqa: F401  (first: its one-BLAS-thread default applies only before numpy loads)
import numpy as np

from fieldcal.earth import Station
from fieldcal.model import params_from_k, terms_from_k
from fieldcal.recording.calibrate import UnknownPlace, calibrate_recording
from fieldcal.recording.detect import interval_means
from fieldcal.recording.importer import import_recording

TESTS = Path(__file__).resolve().parent.parent / "tests"
REAL = TESTS / "data" / "real"


def unpacked(tmp: Path, name: str) -> Path:
    path = tmp / name.removesuffix(".gz")
    path.write_bytes(gzip.decompress((REAL / name).read_bytes()))
    return path


def residuals(recording, calibrate, intervals, gravity) -> tuple[float, float]:
    """RMS of |a| − g (m/s²) over every sample of the intervals, and over their means;
    ``calibrate``: raw (n, 3) to m/s² (n, 3), e.g. a Calibration's ``calibrate``."""
    raw = recording.triads["accelerometer"]
    samples = np.concatenate([raw[a:b] for a, b in intervals])  # a loop over intervals
    per_sample = np.linalg.norm(calibrate(samples), axis=1) - gravity
    per_mean = np.linalg.norm(calibrate(interval_means(raw, intervals)), axis=1) - gravity
    return float(np.sqrt(np.mean(per_sample**2))), float(np.sqrt(np.mean(per_mean**2)))


def pm(values, sigmas, fmt="{:.5g}") -> str:
    return ", ".join(f"{fmt.format(v)} ± {s:.2g}" for v, s in zip(values, sigmas))


def main() -> int:
    sys.path.insert(0, str(TESTS))  # imu_tk's recorded result and its detector, as the tests read them
    from test_real_recordings import imu_tk_in_fieldcal_frame, imu_tk_result, imu_tk_xsens_intervals, overlaps

    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # imu_tk's Xsens recording: 100 Hz counts; where it was made is not published.
        paths = [unpacked(tmp, f"imu_tk_xsens_{k}.mat.gz") for k in ("acc", "gyro")]
        rec = import_recording(paths, "imu_tk")
        g = 9.81744
        cal = calibrate_recording(rec, Station(45.0, 0.0, g))
        acc, gyro = cal.specific_force["accelerometer"], cal.angular_rate["gyroscope"]
        print(f"imu_tk Xsens: {len(cal.poses.intervals)} intervals, {cal.spread.count} distinct; "
              "RMS(|a|-g) per sample %.4g, per interval mean %.4g m/s^2"
              % residuals(rec, acc.calibrate, cal.poses.intervals, g))
        print(f"  acc bias (counts) {pm(acc.bias, acc.sigma[:3])}; scale (counts per m/s^2) "
              f"{pm(np.diag(acc.K), acc.sigma[3:6])}")
        print(f"  gyro scale (counts per rad/s) {pm(np.diag(gyro.K), gyro.sigma[3:6])}; bias (counts) "
              f"{pm(gyro.bias, gyro.sigma[:3])}")
        # imu_tk's own result on these files (tests/data/real/imu_tk_xsens_result.json) on the same
        # intervals: fieldcal's, and fieldcal's overlapped with imu_tk's (its detector, reproduced).
        tk = imu_tk_result()
        (acc_tk, acc_b), (gyro_tk, gyro_b) = tk["accelerometer"], tk["gyroscope"]
        shared = overlaps(cal.poses.intervals, imu_tk_xsens_intervals(rec))
        for label, intervals in (("fieldcal's intervals", cal.poses.intervals),
                                 (f"the {len(shared)} shared with imu_tk's", shared)):
            print(f"  on {label}: RMS(|a|-g) per sample, per interval mean: fieldcal %.4g, %.4g; imu_tk %.4g, "
                  "%.4g m/s^2" % (residuals(rec, acc.calibrate, intervals, g)
                                  + residuals(rec, lambda v: (v - acc_b) @ acc_tk.T, intervals, g)))
        acc_k, gyro_k = imu_tk_in_fieldcal_frame(acc_tk, gyro_tk)
        z_acc = (acc.file_theta - params_from_k(acc_k, acc_b)) / acc.file_sigma
        z_gyro = (gyro.theta - np.r_[gyro_b, np.concatenate(terms_from_k(gyro_k))]) / gyro.sigma
        print(f"  fieldcal − imu_tk in fieldcal's σ, in fieldcal's frame: accelerometer {np.round(z_acc, 2).tolist()} "
              f"(largest {np.abs(z_acc).max():.2f}); gyro bias {np.round(z_gyro[:3], 2).tolist()} (imu_tk's: the "
              f"first 50 s's mean), scale and terms {np.round(z_gyro[3:], 2).tolist()} "
              f"(largest {np.abs(z_gyro[3:]).max():.2f})")

        # imucal's Ferraris session: 102.4 Hz, m/s^2 and deg/s, imucal's own sections.
        path = unpacked(tmp, "imucal_ferraris_session.csv.gz")
        rec = import_recording([path], "imucal", rate_hz=102.4)
        g = 9.81
        cal = calibrate_recording(rec, UnknownPlace(gravity=g))
        acc, gyro = cal.specific_force["accelerometer"], cal.angular_rate["gyroscope"]
        sections = json.loads((REAL / "imucal_ferraris_session_list.json").read_text())
        theirs = np.array([[sections[k]["start"], sections[k]["end"]] for k in
                           ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")])
        shared = overlaps(cal.poses.intervals, theirs)
        print(f"imucal Ferraris: {len(cal.poses.intervals)} intervals, {cal.spread.count} faces, "
              f"{len(gyro.residuals)} turns; on the {len(shared)} intervals shared with imucal's sections: "
              "RMS(|a|-g) per sample %.5g, per interval mean %.4g m/s^2 (fieldcal)"
              % residuals(rec, acc.calibrate, shared, g))
        print(f"  acc bias (m/s^2) {pm(acc.bias, acc.sigma[:3])}; scale {pm(np.diag(acc.K), acc.sigma[3:6])}")
        print(f"  gyro bias (deg/s) {pm(gyro.bias, gyro.sigma[:3])}; scale (deg/s per rad/s) "
              f"{pm(np.diag(gyro.K), gyro.sigma[3:6])}")
        try:
            import imucal
            import pandas as pd
        except ImportError:
            print("  imucal: not installed (pip install imucal)")
        else:
            data = pd.read_csv(path, header=0, index_col=0)
            regions = imucal.ferraris_regions_from_section_list(
                data, pd.read_json(REAL / "imucal_ferraris_session_list.json").T)
            info = imucal.FerrarisCalibration(grav=g).compute(
                regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2", from_gyr_unit="deg/s")
            # imucal calibrates a = R⁻¹K⁻¹(u − b): fieldcal's raw = K·a + bias with K = K_a·R_a;
            # the gyro's K_g·R_g is per deg/s of input, fieldcal's per rad/s (× 180/π).
            M = info.K_a @ info.R_a
            per_sample, per_mean = residuals(rec, lambda v: np.linalg.solve(M, (v - info.b_a).T).T, shared, g)
            print(f"  imucal on the same intervals: RMS(|a|-g) per sample {per_sample:.5g}, per interval mean "
                  f"{per_mean:.4g} m/s^2; acc bias {np.round(info.b_a, 5).tolist()}, scale "
                  f"{np.round(np.diag(M), 5).tolist()}; gyro bias {np.round(info.b_g, 4).tolist()} deg/s, "
                  f"scale {np.round(np.diag(info.K_g @ info.R_g) * 180 / np.pi, 4).tolist()}")
            for ours, K, b in ((acc, M, info.b_a), (gyro, info.K_g @ info.R_g * 180 / np.pi, info.b_g)):
                z = (ours.file_theta - params_from_k(K, b, full=True)) / ours.file_sigma
                print(f"  {ours.name}: fieldcal − imucal in fieldcal's σ, per parameter (bias, scale, the three "
                      f"angles): {np.round(z, 2).tolist()}; largest {np.abs(z).max():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
