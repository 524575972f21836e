"""fieldcal on real recordings made with other tools (tests/data/real, see its README): what
people actually have, with its real noise, bias shifts and short or long rests."""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from fieldcal.earth import Station
from fieldcal.model import calibrate_with
from fieldcal.recording.calibrate import calibrate_recording
from fieldcal.recording.detect import interval_means
from fieldcal.recording.importer import import_recording

REAL = Path(__file__).parent / "data" / "real"
IMU_TK_GRAVITY = 9.81744  # m/s^2, what imu_tk's example app uses for this recording


def unpacked(tmp_path: Path, *names: str) -> list[Path]:
    out = []
    for name in names:
        path = tmp_path / name.removesuffix(".gz")
        path.write_bytes(gzip.decompress((REAL / name).read_bytes()))
        out.append(path)
    return out


@pytest.fixture(scope="module")
def xsens(tmp_path_factory):
    paths = unpacked(tmp_path_factory.mktemp("xsens"), "imu_tk_xsens_acc.mat.gz", "imu_tk_xsens_gyro.mat.gz")
    recording = import_recording(paths, "imu_tk")
    # Where it was recorded is not published: any latitude, the Earth rate is an error term.
    return recording, calibrate_recording(recording, Station(45.0, 0.0, IMU_TK_GRAVITY))


def test_imu_tk_xsens_poses_are_all_found_without_a_rest_option(xsens):
    """The recording starts with ~50 s still; nothing tells fieldcal so. imu_tk's example finds
    38 static intervals with a 50 s rest given; the best-fitting threshold here may split one."""
    recording, cal = xsens
    assert 38 <= len(cal.poses.intervals) <= 40 and cal.spread.count == 14
    assert "quietest" in cal.noise_source
    assert cal.poses.intervals[0, 0] == 0 and cal.poses.intervals[0, 1] > 45 * recording.rate_hz


def test_imu_tk_xsens_calibrated_poses_have_the_local_gravity(xsens):
    """Independent of any solver: each calibrated pose mean's norm is g, better than imu_tk's
    own fit of this data (RMS of |a| - g per interval mean 1.197e-3 m/s^2, issue 11)."""
    recording, cal = xsens
    acc = cal.specific_force["accelerometer"]
    means = interval_means(recording.triads["accelerometer"], cal.poses.intervals)
    norms = np.linalg.norm(calibrate_with(acc.theta, means), axis=1)
    assert np.sqrt(np.mean((norms - IMU_TK_GRAVITY) ** 2)) < 1.197e-3
    gyro = cal.angular_rate["gyroscope"]
    assert np.degrees(np.sqrt(np.mean(gyro.residuals ** 2))) < 0.5  # direction residual, °
