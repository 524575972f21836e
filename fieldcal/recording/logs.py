"""Flight-controller and robot logs -> :class:`Recording`, by the format's own reader.

- PX4 ULog (``.ulg``), read by ``pyulog`` (the ``logs`` extra): the ``sensor_combined`` topic
  (``accelerometer_m_s2``, ``gyro_rad`` on one timestamp, µs), else ``sensor_accel`` and
  ``sensor_gyro`` (instance 0), the gyro put on the accelerometer's timestamps.
- ROS 1 bags (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml``) of
  ``sensor_msgs/Imu``, read by ``rosbags``: see :mod:`fieldcal.recording.bags` (``--topic``).
- ArduPilot DataFlash logs (``.bin``), read by ``pymavlink``: see
  :mod:`fieldcal.recording.dataflash` (``--imu N``).

Each reader is imported only here, when such a file is imported: most users never need it.
What is found is reported like a text import (an :class:`ImportReport`), with the topic in place
of a map, so the session keeps where its samples came from.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE
from fieldcal.recording import Recording
from fieldcal.recording.importer import (FIRST_FEW, GAP_PERIODS, MAX_READING, FileReport, ImportReport,
                                         RecordingImportError)

ULOG, ROS1_BAG, ROS2_BAG, DATAFLASH = "PX4 ULog", "ROS 1 bag", "ROS 2 bag", "ArduPilot DataFlash"
LOG_SUFFIXES = {".ulg": ULOG, ".bag": ROS1_BAG, ".bin": DATAFLASH}
LOG_NAMES = ("a PX4 log (.ulg), a ROS 1 bag (.bag), a ROS 2 bag (its directory) or an ArduPilot "
             "DataFlash log (.bin)")


def log_format(path: str | os.PathLike) -> str | None:
    """The log format a file's name (or a ROS 2 bag's directory) says it is, or None (then it is
    text, with a map)."""
    from fieldcal.recording.bags import bag_root

    root = bag_root(path)
    if root is not None:
        return ROS1_BAG if root.suffix.lower() == ".bag" else ROS2_BAG
    return LOG_SUFFIXES.get(Path(path).suffix.lower())


def import_log(path: str | os.PathLike, topic: str | None = None,
               imu: int | None = None) -> tuple[Recording, ImportReport]:
    """The recording in the log at ``path``. ``topic``: the ROS bag's Imu topic; ``imu``: the
    DataFlash log's IMU instance (each refused for the other formats)."""
    path = os.fspath(path)
    kind = log_format(path)
    if kind is None:
        raise RecordingImportError(f"{path}: not a log format fieldcal reads ({LOG_NAMES}); "
                                   "text files need --map", path)
    if topic is not None and kind not in (ROS1_BAG, ROS2_BAG):
        raise RecordingImportError(f"--topic is for ROS bags; {path} is read as {kind}", path)
    if imu is not None and kind != DATAFLASH:
        raise RecordingImportError(f"--imu is for ArduPilot DataFlash logs; {path} is read as {kind}", path)
    from fieldcal.recording.bags import bag_root
    from fieldcal.recording.inputs import check_input

    check_input(bag_root(path) or path, f"{kind} log")  # a FIFO, a device, a file of zeros: one line
    sha256 = _digest(path)
    damage = ()
    if kind == ULOG:
        t, acc, gyro, topic, damage = _ulog(path)
        notes = ()
    elif kind == DATAFLASH:
        from fieldcal.recording.dataflash import read_dataflash
        t, acc, gyro, topic, notes, damage = read_dataflash(path, imu)
    else:
        from fieldcal.recording.bags import read_bag
        t, acc, gyro, topic, notes = read_bag(path, topic)
    return _recording(path, sha256, kind, topic, t, acc, gyro, notes, damage)


def _digest(path: str) -> str:
    """sha256 of the log's bytes (a ROS 2 bag: of its files' bytes, in name order)."""
    digest = hashlib.sha256()
    try:
        files = sorted(p for p in Path(path).iterdir() if p.is_file()) if Path(path).is_dir() else [Path(path)]
        for file in files:
            with open(file, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    digest.update(block)
    except OSError as exc:
        raise RecordingImportError(f"{path}: cannot read it ({exc.strerror or exc})", path) from None
    return digest.hexdigest()


def _ulog(path: str):
    try:
        from pyulog import ULog
    except ImportError:
        raise RecordingImportError(f"{path}: reading PX4 ULog needs pyulog: pip install 'fieldcal[logs]'",
                                   path) from None
    from fieldcal.recording.noise import captured_output

    try:
        with captured_output() as noise, open(path, "rb") as raw:  # pyulog prints its warnings on damage: said in one line
            reads = _LastRead(raw)
            log = ULog(reads, ["sensor_combined", "sensor_accel", "sensor_gyro"])
    except Exception as exc:  # pyulog raises bare exceptions on a damaged file
        raise RecordingImportError(f"{path}: not a readable ULog ({exc})", path) from None
    damage = ()
    if reads.cut_short is not None:  # pyulog stops there without a word: a short log would pass as whole
        damage = (f"the log ends inside its last message (at byte {reads.cut_short}; cut off mid-write, or a copy "
                  "cut short?): the samples after it are missing",)
    if log.file_corruption:
        from fieldcal.recording.inputs import zero_tail

        said = noise.summary("pyulog")
        zeros = zero_tail(path)[1]
        why = f" (its last {zeros} bytes are zeros: a pre-allocated file's unused end?)" if zeros > 1024 else ""
        damage = (f"pyulog found corrupt data in it{why}: messages were skipped" + (f"; {said}" if said else ""),
                  *damage)
    topics = {(d.name, d.multi_id): d.data for d in log.data_list}
    combined = topics.get(("sensor_combined", 0))
    if combined is not None and len(combined["timestamp"]) >= 2:
        t = combined["timestamp"] * 1e-6
        acc = np.column_stack([combined[f"accelerometer_m_s2[{i}]"] for i in range(3)]).astype(float)
        gyro = np.column_stack([combined[f"gyro_rad[{i}]"] for i in range(3)]).astype(float)
        return t, acc, gyro, "sensor_combined", damage
    accel, rate = topics.get(("sensor_accel", 0)), topics.get(("sensor_gyro", 0))
    if accel is None or rate is None or len(accel["timestamp"]) < 2:
        if damage:
            raise RecordingImportError(f"{path}: damaged: {damage[0]}; no sensor_combined, nor sensor_accel and "
                                       "sensor_gyro samples in what could be read", path)
        raise RecordingImportError(f"{path}: no sensor_combined, nor sensor_accel and sensor_gyro samples in "
                                   "the log: log those topics (SDLOG_PROFILE with sensor comparison or "
                                   "high rate)", path)
    t = accel["timestamp_sample"] * 1e-6 if "timestamp_sample" in accel else accel["timestamp"] * 1e-6
    tg = rate["timestamp_sample"] * 1e-6 if "timestamp_sample" in rate else rate["timestamp"] * 1e-6
    acc = np.column_stack([accel[a] for a in "xyz"]).astype(float)
    gyro = np.column_stack([np.interp(t, tg, rate[a]) for a in "xyz"])
    return t, acc, gyro, "sensor_accel + sensor_gyro (interpolated onto the accelerometer's time)", damage


class _LastRead:
    """The file pyulog reads, watched for how its reading ended. pyulog reads each message as its
    3-byte header (msg_size, msg_type) and then msg_size bytes, and stops without a word when a read
    comes back short: at the end of a whole log only the next header's read finds nothing; in a
    log cut inside a message the header's or the message's read comes back part-filled."""

    def __init__(self, raw):
        self._raw, self.cut_short = raw, None
        self.seek, self.tell, self.close = raw.seek, raw.tell, lambda: None  # closed by its owner

    def read(self, size: int = -1) -> bytes:
        start = self._raw.tell()
        data = self._raw.read(size)
        # None unless this read is short and not a header's read that found the end between messages
        short = len(data) < size and not (size == 3 and not data)
        self.cut_short = (start if size == 3 else start - 3) if short else None  # where the message starts
        return data


def _recording(path, sha256, kind, topic, t, acc, gyro, notes=(), damage=()) -> tuple[Recording, ImportReport]:
    """The Recording and its report. ``damage``: what the format's reader could not read, in
    words; with the samples dropped here as damaged (values no sensor gives, timestamps far
    outside the rest) it is said as a warning, never as a clean recording."""
    t = t_read = np.asarray(t, dtype=float)
    total = len(t)
    # A driver that had no reading logs NaN: not a sample.
    finite = np.isfinite(t) & np.isfinite(acc).all(axis=1) & np.isfinite(gyro).all(axis=1)
    # A value beyond any sensor's range is a damaged message (a DataFlash log has no checksum).
    wild_value = finite & ~((np.abs(acc) <= MAX_READING).all(axis=1) & (np.abs(gyro) <= MAX_READING).all(axis=1))
    usable = finite & ~wild_value
    wild_time = _wild_timestamps(t, usable)
    index = np.flatnonzero(usable & ~wild_time)
    t, acc, gyro = t[index], acc[index], gyro[index]
    if len(t) < 2:
        raise RecordingImportError(f"{path}: {kind} {topic} has {len(t)} sample(s) with finite values: too "
                                   "few to calibrate from" + (f" (damaged: {'; '.join(damage)})" if damage else ""),
                                   path)
    # A timestamp not after every earlier one is a re-sent (or re-ordered) sample.
    keep = np.r_[True, t[1:] > np.maximum.accumulate(t)[:-1]]
    t, acc, gyro, index = t[keep], acc[keep], gyro[keep], index[keep]
    if len(t) < 2:
        raise RecordingImportError(f"{path}: {kind} {topic}: its {total} samples' timestamps never "
                                   "increase (all the same?): the logger's clock is not running", path)
    dt = np.diff(t)
    period = float(np.median(dt))
    widest = int(np.argmax(dt))
    not_used = np.setdiff1d(np.arange(total), index, assume_unique=True) + 1  # 1-based sample numbers
    first = tuple(int(i) for i in not_used[:FIRST_FEW])
    report = FileReport(path=path, name=f"{kind}: {topic}", sha256=sha256,
                        lines=total, samples=len(t), header_lines=0, malformed=len(not_used),
                        malformed_lines=first, rate_hz=1.0 / period, t_first=float(t[0]), t_last=float(t[-1]),
                        gaps=int(np.count_nonzero(dt > GAP_PERIODS * period)), largest_gap_s=float(dt[widest]),
                        largest_gap_line=int(index[widest + 1]) + 1, item="sample")
    recording = Recording(t=t, triads={"accelerometer": acc, "gyroscope": gyro},
                          kinds={"accelerometer": SPECIFIC_FORCE, "gyroscope": ANGULAR_RATE},
                          units={"accelerometer": "m/s^2", "gyroscope": "rad/s"}, sources=(path,),
                          malformed={path: (report.malformed, first)})
    nan = int(np.count_nonzero(~finite))
    repeated = int(np.count_nonzero(~keep))
    dropped = ((f"{nan} samples with NaN or infinite values dropped",) if nan else ()) + (
        (f"{repeated} repeated timestamps dropped",)
        if repeated else ())
    damaged = list(damage)
    if wild_value.any():
        i = int(np.flatnonzero(wild_value)[0])
        damaged.append(f"{int(wild_value.sum())} samples with values beyond any sensor's range (|x| > "
                       f"{MAX_READING:.0e}; the first is sample {i + 1}) not used")
    if wild_time.any():
        i = int(np.flatnonzero(wild_time)[0])
        damaged.append(f"{int(wild_time.sum())} samples with timestamps far outside the rest (the first is sample "
                       f"{i + 1}, at {t_read[i]:.6g} s) not used")
    notes = (f"{kind}: {'' if kind == DATAFLASH else 'topic '}{topic}", *notes, *dropped)
    warnings = (f"{path}: DAMAGED, imported from what could be read: {'; '.join(damaged)}",) if damaged else ()
    return recording, ImportReport(map_path=f"({kind} reader)", map_text="", files=(report,),
                                   alignment=notes, warnings=warnings)


WILD_SPREAD = 3.0  # interquartile ranges beyond the quartiles of the timestamps


def _wild_timestamps(t: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Samples whose timestamp lies far outside the rest (beyond WILD_SPREAD interquartile ranges
    of the quartiles), in a log whose time does not simply increase: a damaged message's time
    (a ULog's 1.8e13 s). Left in, one would make every later sample look "repeated". A log whose
    time only increases is not damaged there, whatever its gaps."""
    wild = np.zeros(len(t), dtype=bool)
    times = t[usable]
    if len(times) < 4 or np.all(np.diff(times) > 0):
        return wild
    q1, q3 = np.percentile(times, [25, 75])
    spread = WILD_SPREAD * (q3 - q1)
    wild[usable] = (times < q1 - spread) | (times > q3 + spread)
    return wild
