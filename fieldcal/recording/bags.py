"""ROS 1 and ROS 2 bags of ``sensor_msgs/Imu`` -> time, specific force (m/s²), rate (rad/s).

Read by ``rosbags`` (pure Python, no ROS install; the ``logs`` extra), imported only when a bag
is given. A ROS 1 bag is a ``.bag`` file; a ROS 2 bag is a directory with ``metadata.yaml``
(sqlite3 or mcap storage), or a ``.db3``/``.mcap`` file inside one.

The topic is ``--topic``, else the bag's only ``sensor_msgs/Imu`` topic. Time is each message's
``header.stamp``; when a driver left the stamps at zero, the bag's receive time instead (said in
the report).

``rosbags`` hands over each message's serialized bytes; deserializing 50 000 messages one by one
in Python would cost most of an import, so the fields are read from all messages at once: in
both ROS 1 and CDR (ROS 2) serialization the stamp sits at bytes 4..12 (after the ROS 1
sequence number, after the CDR encapsulation header) and the 37 float64 of orientation,
angular velocity and linear acceleration with their covariances end the message, whatever the
length of ``frame_id``. The first and the last message are also deserialized by ``rosbags``
itself and must agree, so a bag whose Imu type is laid out otherwise is refused, not misread.
"""
from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from fieldcal.recording.importer import RecordingImportError

IMU_TYPE = "sensor_msgs/msg/Imu"
ROS2_STORAGE_SUFFIXES = (".db3", ".mcap")
_TAIL_FLOATS = 37  # orientation 4, its covariance 9, angular velocity 3 + 9, linear acceleration 3 + 9
_RATE, _ACCEL = slice(13, 16), slice(25, 28)  # in the tail
# The first bytes of each storage format rosbags reads: checked before rosbags is given the file,
# which would otherwise hold a file of junk whole (a 600 MB file of 0xFF took 1.24 GB) to refuse it.
MAGIC = {".bag": (b"#ROSBAG V2.0\n", "ROS 1 bag (version 2.0)"), ".db3": (b"SQLite format 3\x00", "SQLite database"),
         ".mcap": (b"\x89MCAP0\r\n", "MCAP file")}
NOT_STANDARD = "the bag defines the type otherwise; republish the topic as the standard message"


def bag_root(path: str | Path) -> Path | None:
    """The bag ``path`` names (a ROS 1 file, or a ROS 2 directory), or None if it is no bag."""
    path = Path(path)
    if path.suffix.lower() == ".bag" and not path.is_dir():
        return path
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    if path.suffix.lower() in ROS2_STORAGE_SUFFIXES and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return None


def read_bag(path: str, topic: str | None = None):
    """(t s, accelerometer m/s², gyroscope rad/s, the topic, notes) from the bag at ``path``."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise RecordingImportError(f"{path}: reading ROS bags needs rosbags: pip install 'fieldcal[logs]'",
                                   path) from None
    root = bag_root(path) or Path(path)
    check_magic(root)
    try:
        with AnyReader([root]) as reader:
            chosen = _topic(reader, path, topic)
            connections = [c for c in reader.connections if c.topic == chosen]
            raws, bag_ns = [], []
            for _, ns, raw in reader.messages(connections=connections):
                raws.append(raw)
                bag_ns.append(ns)
            if len(raws) < 2:
                raise RecordingImportError(f"{path}: topic {chosen} has {len(raws)} message(s): "
                                           "too few to calibrate from", path)
            first, last = (reader.deserialize(raws[i], IMU_TYPE) for i in (0, -1))
    except RecordingImportError:
        raise
    except Exception as exc:  # rosbags raises its own errors, and OSError/KeyError on damaged files
        raise RecordingImportError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc})", path) from None
    stamps, rate, accel = _fields(path, chosen, raws, ros2=root.suffix.lower() != ".bag")
    for i, msg in ((0, first), (-1, last)):
        expected = np.r_[_vector(msg.angular_velocity), _vector(msg.linear_acceleration)]
        if not np.array_equal(np.r_[rate[i], accel[i]], expected, equal_nan=True) or \
                stamps[i] != msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec:
            raise RecordingImportError(f"{path}: the messages of {chosen} are not laid out as a standard "
                                       f"{IMU_TYPE}: {NOT_STANDARD}", path)
    bag_ns = np.asarray(bag_ns, dtype=np.int64)
    if np.any(stamps == 0):
        ns, clock = bag_ns, "the bag's receive time (header.stamp is zero in some messages)"
    else:
        ns, clock = stamps, "header.stamp"
    order = np.argsort(ns, kind="stable")  # a driver may publish a stamp late: put samples in time order
    # Seconds from the first sample: epoch nanoseconds as float64 seconds would keep only 0.2 µs.
    t = (ns[order] - ns[order[0]]) * 1e-9
    start = datetime.datetime.fromtimestamp(ns[order[0]] * 1e-9, datetime.timezone.utc)
    return (t, accel[order], rate[order], chosen,
            (f"time from {clock}, t = 0 at {start:%Y-%m-%d %H:%M:%S.%f} UTC",))


def check_magic(root: Path) -> None:
    """Refuse, in one line, a bag file (or a ROS 2 bag's storage file) that does not start as its
    format does: read 16 bytes of each, nothing more."""
    files = [root] if not root.is_dir() else sorted(p for p in root.iterdir() if p.suffix.lower() in MAGIC)
    for file in files:
        magic, what = MAGIC.get(file.suffix.lower(), MAGIC[".bag"])
        try:
            with open(file, "rb") as f:
                head = f.read(len(magic))
        except OSError as exc:
            raise RecordingImportError(f"{file}: cannot read it ({exc.strerror or exc})", str(file)) from None
        if head != magic:
            raise RecordingImportError(f"{file}: not a readable ROS bag: it does not start with {magic!r} as a "
                                       f"{what} does (its first bytes are {head[:len(magic)]!r})", str(file))


def _topic(reader, path: str, wanted: str | None) -> str:
    imu = sorted(name for name, info in reader.topics.items() if info.msgtype == IMU_TYPE)
    if wanted is not None:
        if wanted not in reader.topics:
            raise RecordingImportError(f"{path}: no topic {wanted}; {_listing(reader)}", path)
        if wanted not in imu:
            raise RecordingImportError(f"{path}: topic {wanted} is {reader.topics[wanted].msgtype}, not "
                                       f"{IMU_TYPE}; {_listing(reader)}", path)
        return wanted
    if len(imu) == 1:
        return imu[0]
    if not imu:
        raise RecordingImportError(f"{path}: no {IMU_TYPE} topic; {_listing(reader)}", path)
    raise RecordingImportError(f"{path}: {len(imu)} {IMU_TYPE} topics ({', '.join(imu)}): choose one "
                               "with --topic", path)


def _listing(reader) -> str:
    topics = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(reader.topics.items()))
    return f"its topics: {topics or 'none'}"


def _vector(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=float)


def _fields(path: str, topic: str, raws: list[bytes], ros2: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (ns), angular velocity and linear acceleration of every message, in one pass."""
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
    if lengths.min() < 12 + 8 * _TAIL_FLOATS:
        raise RecordingImportError(f"{path}: a message of {topic} has {lengths.min()} bytes, too few for a "
                                   f"standard {IMU_TYPE}: {NOT_STANDARD}", path)
    buffer = np.frombuffer(b"".join(raws), dtype=np.uint8)
    ends = np.cumsum(lengths)
    starts = ends - lengths
    # CDR says its byte order in the encapsulation header (0x0001 little-endian); ROS 1 is little.
    little = buffer[starts + 1] == 1 if ros2 else np.ones(len(raws), dtype=bool)
    # Rows of bytes at those offsets: a view of every window, then one copy of the rows wanted.
    head = np.lib.stride_tricks.sliding_window_view(buffer, 8)[starts + 4]
    tail = np.lib.stride_tricks.sliding_window_view(buffer, 8 * _TAIL_FLOATS)[ends - 8 * _TAIL_FLOATS]
    sec_le, sec_be = (head[:, :4].copy().view(o + "u4")[:, 0] for o in "<>")
    nsec_le, nsec_be = (head[:, 4:].copy().view(o + "u4")[:, 0] for o in "<>")
    stamps = np.where(little, sec_le, sec_be).astype(np.int64) * 10**9 + np.where(little, nsec_le, nsec_be)
    floats = np.where(little[:, None], tail.copy().view("<f8"), tail.copy().view(">f8"))
    return stamps, floats[:, _RATE].astype(float), floats[:, _ACCEL].astype(float)
