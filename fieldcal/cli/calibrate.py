"""``fieldcal calibrate``: a recording (text files and a map, or an imported session) in, a
parameter file out; import, pose detection and the solves in one command."""
from __future__ import annotations

import argparse
import datetime
import time
from dataclasses import replace
from pathlib import Path

_EPILOG = """\
examples:
  fieldcal calibrate acc.txt gyro.txt --map imu_tk --latitude 45.5 --height 120
      imu_tk's two-file layout in raw counts: imported into a new session under ./sessions,
      calibrated, the parameter file written into the session
  fieldcal calibrate sessions/unit7 --config vn100
      a session made by `fieldcal import`; the station and the noise from a device config
  fieldcal calibrate session.csv --map imucal --rate 102.4 --gravity 9.81
      an imucal Ferraris session (six faces up, a full turn about each
      axis): the aligned six-position solution is chosen by itself; no
      latitude: the Earth rate is an error term
  fieldcal calibrate flight.ulg
      a PX4 log (pip install 'fieldcal[logs]'); no place, no gravity:
      normal gravity at 45°, its ±0.3 % worldwide spread in the scale
      factors' σ, with a warning (never the sensor's own norm)
  fieldcal calibrate run.bag --topic /imu/data --latitude 48.1
      a ROS 1 bag, or a ROS 2 bag's directory (sensor_msgs/Imu); an
      ArduPilot DataFlash log (.bin) likewise, its IMU instance by --imu N

Put the unit down by hand in a dozen or more poses (every axis up and down,
and some corners up), still for a few seconds each, turning it between them.
The noise level the static poses are found with comes from the recording's
quietest one-second windows; give --rest S when it starts with S seconds still
to take it from there instead. The gyroscope's bias is the poses' mean
(less the vertical Earth rate), or estimated (--gyro-bias estimate)."""


def add_calibrate_parser(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "calibrate", help="calibrate from a plain recording: poses found automatically, no turntable",
        description="Find the static poses of a hand-held recording, calibrate every\n"
        "accelerometer-like triad by the norm method and the gyroscope from the rotations\n"
        "between poses (scale factors, all six gyro-to-accelerometer misalignment terms; the\n"
        "bias from the still poses' mean or estimated), and write a parameter file.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recording", nargs="+", metavar="RECORDING",
                        help="a session directory from `fieldcal import`, or text files (with --map)")
    parser.add_argument("--map", metavar="MAP", help="import map for text files (see `fieldcal import`)")
    from fieldcal.cli.importing import add_log_options
    add_log_options(parser)
    parser.add_argument("--rate", type=float, metavar="HZ",
                        help="sample rate of text files with no time column (else rate_hz in the map)")
    parser.add_argument("--out", default="sessions", metavar="DIR",
                        help="where the imported session goes (default ./sessions)")
    parser.add_argument("--config", metavar="CONFIG",
                        help="device config: its station, and its triads' noise (exact pose weights)")
    parser.add_argument("--latitude", type=float, metavar="DEG", help="station latitude, °")
    parser.add_argument("--height", type=float, metavar="M", help="station height, m (default 0)")
    parser.add_argument("--gravity", type=float, metavar="M_S2", help="measured local gravity, m/s^2")
    parser.add_argument("--rest", type=float, metavar="S",
                        help="the recording starts with S seconds still: the noise level from there "
                        "(default: from the quietest windows, no rest assumed)")
    parser.add_argument("--min-still", type=float, metavar="S",
                        help="shortest still stretch taken as a pose, s (default 2; shorter poses "
                        "have noisier means)")
    parser.add_argument("--gyro-bias", choices=("poses", "estimate", "rest"), default="poses",
                        help="gyro bias: the still poses' mean, less the vertical Earth rate "
                        "(default; 'rest' is its old name), or estimated with the rotations")
    parser.add_argument("--method", choices=("powell", "lsq"), default="powell",
                        help="accelerometer solver (default powell)")
    parser.add_argument("--table-rate", type=float, metavar="DEG_S",
                        help="the recording has turns on a turntable at this rate (°/s, either sense): "
                        "use them as rate equations too")
    parser.add_argument("--accept-misfit", action="store_true",
                        help="keep a calibration whose fit is far beyond the noise (χ²/dof over 100), "
                        "with a warning, instead of refusing it")
    parser.add_argument("--params", metavar="FILE", help="also write the parameter file here")
    parser.add_argument("--force", action="store_true", help="replace the --params file if it exists")
    from fieldcal.cli.options import add_operator_option, add_spec_option
    add_spec_option(parser)
    add_operator_option(parser)
    from fieldcal.cli.identity import add_unit_serial_option
    add_unit_serial_option(parser, "the unit recorded (default: an imported session's, else the "
                           "--config's device.serial)")
    parser.set_defaults(func=cmd_calibrate)
    return parser


TABLE_RATE_MAX_DEG_S = 2000.0  # the widest full scale of MEMS gyros: no turn above it is measured


def _station(args, config):
    """The station; an UnknownPlace when neither --latitude nor a config says where."""
    from fieldcal.earth import GRAVITY_RANGE_M_S2, HEIGHT_RANGE_M, Station
    from fieldcal.recording.place import UnknownPlace

    # Each option checked by its own name (Station's own checks name its fields, not the options).
    if args.gravity is not None and not GRAVITY_RANGE_M_S2[0] < args.gravity < GRAVITY_RANGE_M_S2[1]:
        raise ValueError(f"--gravity: expected 9.7..9.9 m/s^2 (local gravity), got {args.gravity:g}")
    if args.latitude is not None and not -90.0 <= args.latitude <= 90.0:
        raise ValueError(f"--latitude: expected -90..90°, got {args.latitude:g}")
    if args.height is not None and not HEIGHT_RANGE_M[0] <= args.height <= HEIGHT_RANGE_M[1]:
        raise ValueError(f"--height: expected -500..9000 m above the ellipsoid, got {args.height:g}")
    base = config.station if config is not None else None
    if args.latitude is None and base is None:
        if args.height is not None and args.gravity is None:  # it would be ignored: normal gravity needs the latitude too
            raise ValueError("--height: needs --latitude too (the height only sets local gravity together "
                             "with the latitude), or give --gravity if measured")
        return UnknownPlace(gravity=args.gravity)
    latitude = args.latitude if args.latitude is not None else base.latitude_deg
    height = args.height if args.height is not None else (base.height_m if base else 0.0)
    gravity = args.gravity if args.gravity is not None else (base.gravity_m_s2 if base else None)
    return Station(latitude, height, gravity)


def _recording(args, serial: str | None):
    """(recording, session directory, import summary lines); for files, the session directory is
    a function that writes the session and returns its writer, still open for the parameter
    file: called once the calibration has succeeded, so that a refused one leaves nothing behind.
    ``serial``: the unit's, as given (--unit-serial, the config's), kept in a session imported
    here; checked against the serial an imported session was given."""
    from fieldcal.recording.store import load_recording

    from fieldcal.recording.logs import LOG_NAMES, log_format

    first = Path(args.recording[0])
    if len(args.recording) == 1 and first.is_dir() and log_format(first) is None:
        if args.map is not None or args.topic is not None or args.imu is not None:
            option = "--map" if args.map is not None else "--topic" if args.topic is not None else "--imu"
            raise ValueError(f"calibrate: {first} is a session: {option} is for the files it was imported from")
        recording = load_recording(first)
        if serial is not None and recording.unit_serial not in (None, serial):
            raise ValueError(f"calibrate: {first} was imported as unit {recording.unit_serial!r}, not {serial!r} "
                             "(--unit-serial, or the --config's device.serial)")
        if serial is not None and recording.unit_serial is None:
            recording = recording.replaced(unit_serial=serial)
        return recording, first, []
    from fieldcal.cli.importing import read_recording, summary_lines
    from fieldcal.recording.store import write_recording

    if args.map is None and not (len(args.recording) == 1 and log_format(first)):
        raise ValueError("calibrate: text files need --map (a name in configs/recordings or a YAML "
                         f"path); or give one session directory from `fieldcal import`, or {LOG_NAMES}")
    recording, report = read_recording(args.recording, args.map, args.rate, args.topic, args.imu)
    recording = recording.replaced(unit_serial=serial)
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")

    def save():
        from fieldcal.atomic import new_named_directory
        directory = new_named_directory(args.out, f"recording-{first.stem}-{stamp}", option="--out")
        return write_recording(recording, directory, report=report)

    return recording, save, summary_lines(recording, report)


def cmd_calibrate(args) -> int:
    from fieldcal.cli.startup import imports_uncollected, reuse_freed_memory

    with imports_uncollected():  # numpy, scipy.linalg and fieldcal's modules: see imports_uncollected
        # scipy first, from here: CPython 3.11 grows the frame stack in 16 KiB chunks, mapped and
        # unmapped as calls cross a chunk's end. scipy's import runs numpy.f2py's module body
        # (thousands of calls); at the depth of fieldcal's own import chain they crossed one some
        # 900 times (an mmap, a munmap and a page fault each); from here, some 40 (strace).
        import scipy.linalg  # noqa: F401
        # Not scipy.optimize: the norm method's search imports it when it runs (solvers.norm).
        # A Ferraris session or a sub-model is solved without it (~0.13 s CPU of 0.63, 20 MiB); a
        # full recording pays its import at the search, where the later collections scan its
        # objects, not frozen here (~1 % of a 1x run).
        from fieldcal.recording.calibrate import RecordingSettings, UnknownPlace, calibrate_recording
        from fieldcal.recording.detect import DetectorSettings
        from fieldcal.recording.results import MISFIT_CAUSES, misfits, noise_lines, parameter_file, summary_lines
        from fieldcal.session.capture import SessionWriter

        from fieldcal.cli.options import accept_after, load_spec_option, operator_option

    operator = operator_option(args)  # refused before the work, not after it
    config = None
    if args.config:  # the config module (and the drivers it names) only when one is given
        from fieldcal.config import load_config
        config = load_config(args.config)
    spec = load_spec_option(args)
    station = _station(args, config)
    if args.table_rate is not None and not 0 < args.table_rate <= TABLE_RATE_MAX_DEG_S:
        raise ValueError(f"--table-rate: expected a rate above 0 and up to {TABLE_RATE_MAX_DEG_S:g} °/s (a "
                         f"gyro's widest range), got {args.table_rate:g}")
    if args.rate is not None and not args.rate > 0:
        raise ValueError(f"--rate: expected a sample rate above 0 Hz, got {args.rate:g}")
    if args.rest is not None and not args.rest > 0:
        raise ValueError(f"--rest: expected a positive number of seconds, got {args.rest:g}")
    if args.min_still is not None and not args.min_still > 0:
        raise ValueError(f"--min-still: expected a positive number of seconds, got {args.min_still:g}")
    if args.params:  # refused before anything is imported or written
        from fieldcal.session.output import check_output_path
        check_output_path(args.params, force=args.force, option="--params")
    started = time.perf_counter()
    from fieldcal.cli.identity import unit_serial
    reuse_freed_memory()  # before the samples and the calibration's temporaries come and go
    recording, directory, imported = _recording(args, unit_serial(args, config))
    for line in imported:
        print(line)
    triads = config.device.triads if config else ()
    noise = {t.name: t.noise for t in triads if t.noise is not None}
    tempco = {t.name: t.scale_tempco_ppm_per_k for t in triads if t.scale_tempco_ppm_per_k is not None}
    detector = DetectorSettings(init_rest_s=args.rest)
    if args.min_still is not None:
        detector = replace(detector, min_static_s=args.min_still)
    settings = RecordingSettings(detector=detector, method=args.method,
                                 estimate_gyro_bias=args.gyro_bias == "estimate", noise=noise,
                                 table_rate_deg_s=args.table_rate, scale_tempco_ppm_per_k=tempco)
    cal = calibrate_recording(recording, station, settings)
    misfit = misfits(cal)
    if misfit and not args.accept_misfit:  # before anything is written
        raise ValueError(f"calibrate: {'; '.join(misfit)}: {MISFIT_CAUSES}; give --accept-misfit to keep it")
    station = cal.place
    pf = parameter_file(cal, recording, station, device_name=config.device.name if config else None,
                        operator=operator, device_serial=recording.unit_serial)
    # Files: their session, written now, its writer kept open for the parameter file; an imported
    # session is reopened (refused if another fieldcal is writing it).
    writer = directory() if callable(directory) else SessionWriter.append_to(directory)
    directory = writer.directory
    try:
        writer.write_parameters(pf)  # parameters-NNN.yaml: an earlier calibration is kept
    finally:
        writer.close()
    if isinstance(station, UnknownPlace):
        gyro = ("; the Earth rate is carried as an error in the gyro's bias and rotations"
                if any(kind == "angular_rate" for kind in recording.kinds.values()) else "")
        print(f"WARNING: where the recording was made is not known (give --latitude, and --gravity if "
              f"measured): g = {station.gravity:.6f} m/s^2 from {station.gravity_source}{gyro}")
    else:
        print(f"station: latitude {station.latitude_deg:g}°, height {station.height_m:g} m, g = "
              f"{station.gravity:.6f} m/s^2 ({station.gravity_source})")
    for line in misfit:
        print(f"WARNING: kept (--accept-misfit): {line}: {MISFIT_CAUSES}")
    for line in noise_lines(cal, bool(noise)):
        print(line)
    for line in summary_lines(cal):
        print(line)
    ours = writer.parameters_written  # numbered, never overwritten: parameters.yaml may be a later run's
    print(f"\nparameter file: {directory / 'parameters.yaml'} (a copy of "
          f"{ours.name})  ({time.perf_counter() - started:.2f} s)")
    if args.params:
        from fieldcal.session.output import save_parameter_file
        written = save_parameter_file(pf, args.params, force=args.force, option="--params",
                                      data=ours.read_bytes())  # pf's text, made once
        print(f"parameter file: {written}")
    return accept_after(args, spec, ours, 0 if not cal.failures else 1,
                        source="calibrate")
