"""``fieldcal import``: text recordings -> a recording session, with a short summary.

``add_import_parser(sub)`` adds the command to ``fieldcal``'s subparsers; ``cmd_import`` raises
ValueError subclasses with one-line messages, which ``fieldcal.cli.main`` prints as
``fieldcal: <message>`` with exit status 2. ``main(argv)`` does the same on its own
(``python -m fieldcal.cli.importing ...``).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from fieldcal.paths import shipped_names

if TYPE_CHECKING:
    from fieldcal.recording import Recording
    from fieldcal.recording.importer import ImportReport

_EPILOG = """\
examples:
  fieldcal import acc.txt gyro.txt --map imu_tk --out sessions/unit7
      two files of "timestamp x y z" lines (accelerometer, then gyroscope), raw counts
  fieldcal import log.csv --map single-csv --out sessions/unit7
      one CSV with time in ms, accelerometer in mg and gyroscope in deg/s
  fieldcal import log.txt --map my-layout.yaml --out sessions/unit7
      any layout: copy a map from configs/recordings/ and edit its columns and units
  fieldcal import session.csv --map imucal --rate 102.4 --out sessions/unit7
      columns found by their header names, no time column: the rate given
  fieldcal import flight.ulg --out sessions/unit7
      a PX4 log: sensor_combined (pip install 'fieldcal[logs]')
  fieldcal import run.bag --topic /imu/data --out sessions/unit7
      a ROS 1 bag, or a ROS 2 bag's directory: sensor_msgs/Imu in m/s^2 and rad/s,
      time from header.stamp (--topic needed only when it has several Imu topics)
  fieldcal import 00000042.BIN --imu 1 --out sessions/unit7
      an ArduPilot DataFlash log: the IMU messages of instance 1 (default 0)

The map says, per file, the delimiter, the time column and its unit, and for each triad its
three columns, kind (specific_force or angular_rate), unit and an optional scale. Lines that
do not parse are counted and listed by line number, never used; time must increase strictly.
Several files are put on the first file's timestamps (the others interpolated linearly unless
their timestamps are the same)."""


def add_import_parser(sub) -> argparse.ArgumentParser:
    maps = ", ".join(shipped_names("import map")) or "none yet"
    parser = sub.add_parser(
        "import", help="turn a recording (text files) into a session for calibration",
        description="Read a continuous recording of a unit from delimited text files, as an\n"
        "import map describes them, or from one log (PX4 ULog, ROS 1 or 2 bag, ArduPilot\n"
        "DataFlash), put all triads on one time base, and write it as a new\n"
        "session directory. Prints what was read: samples, rate, duration, malformed lines\n"
        "(with line numbers), gaps, and whether a file was interpolated.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="the recording's files, in the order of the map's entries; or one log")
    parser.add_argument("--map", metavar="MAP",
                        help=f"import map for text files: a name in configs/recordings ({maps}) or a YAML "
                        "path; a log (.ulg, .bag, a ROS 2 bag directory, .bin) needs none")
    add_log_options(parser)
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="the new session directory (must not exist, or be empty)")
    parser.add_argument("--rate", type=float, metavar="HZ",
                        help="sample rate of files with no time column (else rate_hz in the map)")
    from fieldcal.cli.identity import add_unit_serial_option
    add_unit_serial_option(parser, "the unit recorded (kept in the session; `calibrate` uses it)")
    parser.set_defaults(func=cmd_import)
    return parser


def add_log_options(parser) -> None:
    """The options that choose what is read from a log (import and calibrate)."""
    parser.add_argument("--topic", metavar="TOPIC",
                        help="a ROS bag's sensor_msgs/Imu topic (default: its only one)")
    parser.add_argument("--imu", type=int, metavar="N",
                        help="an ArduPilot DataFlash log's IMU instance (default 0)")


def cmd_import(args) -> int:
    # Here, not at the top: `fieldcal --help` builds this parser without numpy.
    from fieldcal.recording.importer import RecordingImportError
    from fieldcal.recording.store import save_recording

    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise RecordingImportError(f"{out}: already exists and is not empty (give --out a new "
                                   "directory)", str(out))
    if args.rate is not None and not args.rate > 0:
        raise RecordingImportError(f"--rate: expected a sample rate above 0 Hz, got {args.rate:g}")
    recording, report = read_recording(args.files, args.map, args.rate, args.topic, args.imu)
    if args.unit_serial is not None:
        recording = recording.replaced(unit_serial=args.unit_serial)
    try:
        directory = save_recording(recording, out, report=report)
    except OSError as exc:
        raise RecordingImportError(f"{out}: cannot write the session ({exc.strerror or exc})",
                                   str(out)) from None
    for line in summary_lines(recording, report):
        print(line)
    print(f"session: {directory}")
    return 0


def read_recording(files, map_name, rate_hz=None, topic=None, imu=None) -> tuple[Recording, ImportReport]:
    """A log by its format's reader, or text files by their import map."""
    from fieldcal.recording.import_map import load_import_map
    from fieldcal.recording.importer import RecordingImportError, import_with_report
    from fieldcal.recording.logs import LOG_NAMES, import_log, log_format

    if map_name is None:
        if len(files) == 1 and log_format(files[0]) is not None:
            return import_log(files[0], topic, imu)
        raise RecordingImportError("text files need --map (a name in configs/recordings or a YAML path); "
                                   f"{LOG_NAMES} needs none")
    if topic is not None or imu is not None:
        raise RecordingImportError(f"--{'topic' if topic is not None else 'imu'} is for logs; text files are "
                                   "read by their map")
    return import_with_report(files, load_import_map(map_name), rate_hz)


def summary_lines(recording: Recording, report: ImportReport) -> list[str]:
    """What was read and done, a few lines per file; warnings last, in capitals."""
    from fieldcal.recording.importer import GAP_PERIODS

    n = len(report.files)
    how = report.map_path if report.map_path.startswith("(") else f"with the map {report.map_path}"
    lines = [f"imported {n} file{'s' * (n != 1)} {how}:"]
    for f in report.files:
        lines.append(f"  {f.name}: {f.path}: {f.samples} samples of {f.lines} {'lines' if f.item == 'line' else 'read'}, "
                     f"{f.rate_hz:.6g} Hz, t {f.t_first:.6g} .. {f.t_last:.6g} s")
        if f.header_lines:
            lines.append(f"    {_count(f.header_lines, 'header line')} skipped")
        if f.zero_tail:
            lines.append(f"    {_count(f.zero_tail, 'NUL byte')} after the last line (a pre-allocated file's unused "
                         "end?) not read")
        if f.malformed:
            first = ", ".join(map(str, f.malformed_lines))
            more = ", ..." if f.malformed > len(f.malformed_lines) else ""
            cut = f" (line {f.lines} has no line end: cut off mid-write?)" if f.cut_off else ""
            what = "malformed line" if f.item == "line" else f.item  # a log: its samples (messages)
            lines.append(f"    {_count(f.malformed, what)} not used: {first}{more}{cut}")
        else:
            lines.append("    no malformed lines" if f.item == "line" else f"    every {f.item} used")
        if f.gaps:
            lines.append(f"    {_count(f.gaps, 'gap')} longer than {GAP_PERIODS:g} sample periods, "
                         f"the largest {f.largest_gap_s:.6g} s before {f.item} {f.largest_gap_line}")
    lines += [f"  {note}" for note in report.alignment]
    triads = ", ".join(f"{name} ({recording.kinds[name]}, {recording.units[name]})"
                       for name in recording.triads)
    lines.append(f"recording: {len(recording.t)} samples, {recording.rate_hz:.6g} Hz, "
                 f"{recording.duration_s:.6g} s; {triads}")
    lines += [f"WARNING: {w}" for w in report.warnings]
    return lines


def _count(k: int, word: str) -> str:
    return f"{k} {word}{'s' * (k != 1)}"


def main(argv=None) -> int:
    """The command on its own, reporting errors as ``fieldcal.cli.main`` does."""
    parser = argparse.ArgumentParser(prog="fieldcal")
    add_import_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["import", *(sys.argv[1:] if argv is None else argv)])
    try:
        return args.func(args)
    except ValueError as exc:
        print(f"fieldcal: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
