"""Recordings as people keep them: gzip/xz/bzip2-compressed text read through, and MATLAB
MAT-files (v5, by scipy.io.loadmat) read from the variable the map names; a v7.3 (HDF5) file
is named as such. Each gives the very samples of the text it was made from."""
from __future__ import annotations

import bz2
import gzip
import hashlib
import lzma

import numpy as np
import pytest
from scipy.io import savemat

from fieldcal.cli.main import main
from fieldcal.recording.importer import RecordingImportError, import_recording, import_with_report

from tests.test_real_recordings import REAL  # noqa: F401  (tests/data/real)

IMU_TK = ("imu_tk_xsens_acc.mat.gz", "imu_tk_xsens_gyro.mat.gz")
ROWS = 3000  # the first 30 s: enough to compare, quick to write


def plain_text(tmp_path, rows=ROWS):
    """imu_tk's two Xsens files, cut to ``rows`` lines, unpacked: the reference."""
    paths = []
    for name in IMU_TK:
        text = gzip.decompress((REAL / name).read_bytes()).splitlines(keepends=True)[:rows]
        path = tmp_path / name.removesuffix(".gz")
        path.write_bytes(b"".join(text))
        paths.append(path)
    return paths


@pytest.mark.parametrize("suffix, pack", [(".gz", gzip.compress), (".xz", lzma.compress), (".bz2", bz2.compress)])
def test_compressed_text_is_read_through(tmp_path, suffix, pack):
    plain = plain_text(tmp_path)
    packed = []
    for path in plain:
        target = path.with_name(path.name + suffix)
        target.write_bytes(pack(path.read_bytes()))
        packed.append(target)
    reference = import_recording(plain, "imu_tk")
    recording, report = import_with_report(packed, "imu_tk")
    np.testing.assert_array_equal(recording.t, reference.t)
    for name in reference.triads:
        np.testing.assert_array_equal(recording.triads[name], reference.triads[name])
    # The session's provenance is the file as given, not its unpacked text.
    assert report.files[0].sha256 == hashlib.sha256(packed[0].read_bytes()).hexdigest()


def test_a_damaged_compressed_file_is_one_line(tmp_path):
    plain = plain_text(tmp_path)
    damaged = tmp_path / "acc.txt.gz"
    damaged.write_bytes(gzip.compress(plain[0].read_bytes())[:-200])
    with pytest.raises(RecordingImportError, match=r"acc.txt.gz: gzip-compressed, but it cannot be unpacked"):
        import_recording([damaged, plain[1]], "imu_tk")


def _mat_map(tmp_path, variables=("acc", "gyro")):
    lines = ["files:"]
    for variable, triad, kind in zip(variables, ("accelerometer", "gyroscope"), ("specific_force", "angular_rate")):
        name = f"variable: {variable}, " if variable else ""
        lines.append(f"  - {{{name}delimiter: null, time: {{column: 0, unit: s}}, triads: {{{triad}: "
                     f"{{columns: [1, 2, 3], kind: {kind}, unit: count}}}}}}")
    path = tmp_path / "mat.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_matlab_v5_file_gives_the_samples_of_its_text(tmp_path):
    plain = plain_text(tmp_path)
    reference = import_recording(plain, "imu_tk")
    mats = []
    for path, variable in zip(plain, ("acc", "gyro")):
        mat = tmp_path / f"{variable}_v5.mat"
        # Beside the samples, what such files also hold: a scalar rate and a note.
        savemat(mat, {variable: np.loadtxt(path), "fs": 100.0, "note": "xsens"})
        mats.append(mat)
    recording = import_recording(mats, _mat_map(tmp_path))
    np.testing.assert_array_equal(recording.t, reference.t)
    for name in reference.triads:
        np.testing.assert_array_equal(recording.triads[name], reference.triads[name])
    # Its only matrix needs no name.
    assert len(import_recording(mats, _mat_map(tmp_path, (None, None))).t) == ROWS


def test_a_matlab_file_with_several_matrices_asks_which(tmp_path):
    plain = plain_text(tmp_path)
    mat = tmp_path / "both.mat"
    savemat(mat, {"acc": np.loadtxt(plain[0]), "gyro": np.loadtxt(plain[1])})
    with pytest.raises(RecordingImportError, match=r"2 numeric matrices \(acc \(3000×4\), gyro \(3000×4\)\): "
                                                   r"name the one to read \(variable: NAME"):
        import_recording([mat, plain[1]], _mat_map(tmp_path, (None, None)))
    with pytest.raises(RecordingImportError, match=r"no numeric matrix 'accel' \(its matrices: acc"):
        import_recording([mat, plain[1]], _mat_map(tmp_path, ("accel", None)))
    wide = tmp_path / "wide.mat"
    savemat(wide, {"acc": np.loadtxt(plain[0]).T})
    with pytest.raises(RecordingImportError, match=r"acc is 4×3000: the samples must be its rows"):
        import_recording([wide, plain[1]], _mat_map(tmp_path, (None, None)))


def test_a_matlab_v73_file_is_named(tmp_path):
    """v7.3 is HDF5 under a 128-byte MATLAB header (then HDF5's signature at byte 512)."""
    plain = plain_text(tmp_path)
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Fri Nov 27 07:00:00 2026 HDF5 schema 1.00 ."
    v73 = tmp_path / "acc73.mat"
    v73.write_bytes(header.ljust(128, b" ") + b"\0" * 384 + b"\x89HDF\r\n\x1a\n" + b"\0" * 64)
    with pytest.raises(RecordingImportError, match=r"acc73.mat: a MATLAB v7.3 MAT-file \(HDF5\).*-v7"):
        import_recording([v73, plain[1]], "imu_tk")


def test_fieldcal_calibrate_reads_imu_tks_compressed_files_as_they_are(tmp_path, capsys):
    """Before: 'no valid sample ... check the map' for the .gz files."""
    code = main(["calibrate", *(str(REAL / n) for n in IMU_TK), "--map", "imu_tk", "--gravity", "9.81744",
                 "--out", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "51175 samples" in out


def test_an_accelerometer_only_recording_speaks_only_of_the_accelerometer(tmp_path, capsys):
    """Before: 'the rotations for the gyro' and a warning about the gyro's Earth-rate error."""
    from drivers.sim.handheld import simulate_handheld, to_text

    acc, _ = to_text(simulate_handheld(2), tmp_path / "text")
    mapping = tmp_path / "acc.yaml"
    mapping.write_text("files:\n  - {delimiter: null, time: {column: 0, unit: s}, triads: {accelerometer: "
                       "{columns: [1, 2, 3], kind: specific_force, unit: count}}}\n")
    code = main(["calibrate", str(acc), "--map", str(mapping), "--out", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "accelerometer" in out and "norm method" in out
    assert "gyro" not in out.lower() and "earth rate" not in out.lower(), out
