"""``fieldcal thermal``: a PX4 thermal-calibration log (a cold-soaked board warming on the bench,
held still) in, each triad's thermal model out (``fieldcal.recording.thermal_log``)."""
from __future__ import annotations

import argparse

PROCEDURE = "px4-thermal-log"

_EPILOG = """\
examples:
  fieldcal thermal warmup.ulg
      the accelerometer's and gyro's bias against temperature, order and σ per axis
  fieldcal thermal warmup.ulg --params thermal.yaml
      also write them as a parameter file; `fieldcal export thermal.yaml --format px4`
      then writes TC_A0_* and TC_G0_* (and nothing else: one still pose calibrates no
      offset, scale or misalignment)
  fieldcal thermal warmup.ulg --onto field.yaml --at 24.5 --params full.yaml
      the thermal models added to a field calibration made at 24.5 °C: its offsets,
      scales and misalignments, and how the biases move from there

Record as PX4's thermal calibration asks: SDLOG_PROFILE's thermal calibration bit
(2) set, the board cold-soaked, then powered and left still while it warms."""


def add_thermal_parser(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "thermal", help="fit each triad's bias against temperature from a PX4 thermal-calibration log",
        description="Fit the accelerometer's and gyro's bias against temperature from a PX4\n"
        "thermal-calibration log (sensor_accel and sensor_gyro with their temperatures, the\n"
        "board still while it warms): per axis a polynomial about the middle of the range,\n"
        "its order chosen from the data (likelihood-ratio test), each term with its 1σ.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", metavar="LOG", help="the PX4 log (.ulg)")
    parser.add_argument("--instance", type=int, default=0, metavar="N",
                        help="the sensors' instance (multi_id) in the log (default 0)")
    parser.add_argument("--at", type=float, metavar="C",
                        help="the reference temperature, °C (default: the middle of the logged range); with "
                        "--onto, the temperature that file's offsets were calibrated at")
    parser.add_argument("--onto", metavar="PARAMS",
                        help="a parameter file (a field calibration of the same unit, at --at °C): the "
                        "thermal models are added to its accelerometer and gyroscope in --params")
    parser.add_argument("--params", metavar="FILE", help="also write the thermal models as a parameter file here")
    parser.add_argument("--force", action="store_true", help="replace the --params file if it exists")
    parser.set_defaults(func=cmd_thermal)
    return parser


def cmd_thermal(args) -> int:
    from pathlib import Path

    import numpy as np

    from fieldcal.recording.thermal_log import fit_held_thermal, read_thermal_ulog
    from fieldcal.report import thermal_table
    from fieldcal.units import BIAS, operator_unit

    if Path(args.log).suffix.lower() != ".ulg":
        raise ValueError(f"thermal: {args.log}: expected a PX4 log (.ulg)")
    if not 0 <= args.instance <= 255:
        raise ValueError(f"--instance: expected 0..255 (a ULog multi_id), got {args.instance}")
    if args.onto is not None and args.at is None:
        raise ValueError("--onto: give --at, the temperature (°C) that file's offsets were calibrated at: the "
                         "thermal model moves the biases from there")
    if args.onto is not None and not args.params:
        raise ValueError("--onto: give --params, where the file with the thermal models goes")
    inputs = [args.log] + ([args.onto] if args.onto else [])
    if args.params:  # refused before the log is read
        from fieldcal.session.output import check_output_path
        check_output_path(args.params, force=args.force, option="--params", inputs=inputs)
    base = None
    if args.onto is not None:
        from fieldcal.paramfile import load
        base = load(args.onto)
    triads = read_thermal_ulog(args.log, args.instance)
    calibrations, fits = [], []
    for triad in triads:
        low, high = float(triad.temperature_c.min()), float(triad.temperature_c.max())
        if args.at is not None and not low <= args.at <= high:
            raise ValueError(f"--at: {args.at:g} °C is outside the log's {triad.topic} temperatures {low:.2f} to "
                             f"{high:.2f} °C (the model does not extrapolate)")
        fit = fit_held_thermal(triad, reference_c=args.at)
        fits.append(fit)
        factor, unit = operator_unit(triad.kind, triad.unit, BIAS)
        chi2 = ", ".join(f"order {k}: {v:.1f}" for k, v in fit.chi2_by_order.items())
        device = f", device id {triad.device_id}" if triad.device_id is not None else ""
        print(f"{triad.name} ({triad.topic} instance {args.instance}{device}): {len(triad.t)} samples over "
              f"{triad.t[-1] - triad.t[0]:.0f} s in {fit.windows} windows, a window mean's σ "
              f"{', '.join(f'{s * factor:.3g}' for s in fit.window_sigma)} {unit}; χ² {chi2} "
              f"({fit.dof} degrees of freedom at the order kept)")
        print(thermal_table(fit.calibration))
        if fit.inflated:  # kept, its σ widened by the misfit: said, with the likely causes
            print(f"WARNING: {triad.name} fits with χ²/dof {fit.chi2 / fit.dof:.3g} for the scatter of its window "
                  f"means: its σ are widened {np.sqrt(fit.chi2 / fit.dof):.2g} times (noise slower than a window, "
                  "or was the board moved, or did the reading jump, during the warm-up?)")
        calibrations.append(fit.calibration)
    print("K and the bias itself are not calibrated by one still pose (gravity and the Earth rate are "
          "in every reading): the model is the change of the bias from its reference temperature.")
    ids = [f"TC_{'A' if t.kind == 'specific_force' else 'G'}0_ID = {t.device_id}" for t in triads
           if t.device_id is not None]
    if ids:  # the parameter file has no place for PX4's sensor ids; `export --format px4` asks for them
        print(f"PX4 sensor ids in the log: {', '.join(ids)}")
    if args.params:
        from fieldcal.paramfile import ParameterFile
        from fieldcal.recording.place import UnknownPlace
        from fieldcal.recording.results import _file_station
        from fieldcal.recording.thermal_log import onto
        from fieldcal.session.output import save_parameter_file

        data = [np.r_[t.t, t.temperature_c] for t in triads] + [t.values for t in triads]
        if base is not None:
            pf = onto(base, fits, PROCEDURE, data)
        else:
            pf = ParameterFile.from_solutions(calibrations, inputs=data, station=_file_station(UnknownPlace()),
                                              procedure=PROCEDURE, method="lsq")
        written = save_parameter_file(pf, args.params, force=args.force, option="--params", inputs=inputs)
        print(f"parameter file: {written}")
    return 0
