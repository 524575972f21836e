"""The ``fieldcal`` command."""
from __future__ import annotations

import argparse
import sys

import numpy as np

from fieldcal import __version__


def _seed(text: str) -> int:
    value = int(text) if text.lstrip("-").isdigit() else -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return value


def _progress_printer(stream):
    interactive = stream.isatty()

    def progress(done: int, total: int, label: str) -> None:
        if interactive:
            print(f"\r  simulating segment {done}/{total} ({label})   ", end="", file=stream, flush=True)
            if done == total:
                print(file=stream)
        elif done == total or done % 9 == 0:
            print(f"  simulated segment {done}/{total}", file=stream, flush=True)
    return progress


def cmd_demo(args) -> int:
    from drivers.sim.device import paper_mimu
    from fieldcal.earth import Station
    from fieldcal.report import solution_header, solution_table
    from fieldcal.simcal import run_simulated_calibration

    station = Station(args.latitude, args.height, args.gravity)
    device = paper_mimu(raw_counts=args.raw_counts)
    print(f"fieldcal {__version__} demo: procedure {args.procedure} against the simulated MIMU "
          f"(paper Tables 3-4{', raw 16-bit counts' if args.raw_counts else ''}), seed {args.seed}")
    print(f"station: latitude {station.latitude_deg:.4f}°, height {station.height_m:.0f} m, "
          f"g = {station.gravity:.6f} m/s² ({station.gravity_source})")
    cal = run_simulated_calibration(args.seed, args.procedure, device, station,
                                    method=args.method, progress=_progress_printer(sys.stderr))
    seconds = cal.plan.windows[-1].start + cal.plan.windows[-1].duration
    print(f"simulated {seconds:.0f} s of {len(cal.plan.attitudes)} positions at 250 Hz; "
          "solved from the window averages\n")
    worst = 0.0
    for name, sol in cal.solutions.items():
        print(solution_header(sol))
        print(solution_table(sol, cal.truth[name]))
        print()
        worst = max(worst, float(np.max(np.abs(sol.theta - cal.truth[name]) / sol.sigma)))
    for name, reason in cal.failures.items():
        print(f"{name}: not calibrated: {reason}")
    if not cal.solutions:
        return 1
    print(f"largest error: {worst:.2f}σ")
    if args.params:
        from fieldcal.paramfile import ParameterFile, TriadParameters, hash_inputs, save
        pf = ParameterFile.build(
            triads=tuple(TriadParameters.from_solution(s) for s in cal.solutions.values()),
            procedure=cal.procedure.name, method=args.method, station=station,
            input_sha256=hash_inputs(*(p.data for p in cal.problems.values())), simulation=True)
        save(pf, args.params)
        print(f"parameter file written to {args.params}")
    return 0


def cmd_monitor(args) -> int:
    from fieldcal.config import load_config
    from fieldcal.monitor import run_monitor

    config = load_config(args.config)
    return run_monitor(config, sys.stdout, sys.stderr, max_samples=args.samples,
                       max_seconds=args.seconds)


def cmd_sim_serve(args) -> int:
    import time

    from drivers.sim.device import paper_mimu
    from drivers.sim.serve import SimulatedDevices
    from fieldcal.earth import Station
    from fieldcal.positions import load_procedure

    station = Station(args.latitude, args.height)
    positions = load_procedure("field-18").positions
    if not 1 <= args.position <= len(positions):
        raise ValueError(f"--position: expected 1..{len(positions)} (field-18), got {args.position}")
    devices = SimulatedDevices(
        paper_mimu(raw_counts=args.raw_counts), station.gravity, station.latitude_rad,
        imu_protocol=args.imu_protocol, table_protocol=args.table_protocol, transport=args.transport,
        speed=args.speed, seed=args.seed, rate_hz=args.rate,
        attitude=positions[args.position - 1].attitude)
    with devices:
        print(f"simulated MIMU ({args.imu_protocol}, {args.rate:g} Hz, field-18 position "
              f"{args.position}): {devices.imu_url}")
        if devices.table_url:
            print(f"simulated rate table ({args.table_protocol}): {devices.table_url}")
        print("serving until Ctrl-C", flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            print(f"stopped after {devices.samples_sent} samples")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fieldcal", description="Field calibration station for "
                                     "MIMU accelerometer, gyroscope and inclinometer triads.")
    parser.add_argument("--version", action="version", version=f"fieldcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = sub.add_parser("demo", help="calibrate the simulated MIMU headless and compare with its truth",
                          description="Run a procedure against the simulated MIMU (errors of paper "
                          "Table 3, noise of Table 4), solve every triad with the norm method and "
                          "print the solved parameters beside the simulator's truth.")
    demo.add_argument("--seed", type=_seed, default=1, help="random seed (default 1)")
    demo.add_argument("--procedure", default="field-18", help="procedure name or YAML path "
                      "(default field-18)")
    demo.add_argument("--method", choices=("powell", "lsq"), default="powell",
                      help="solver (default powell)")
    demo.add_argument("--latitude", type=float, default=40.0, help="station latitude, degrees (default 40)")
    demo.add_argument("--height", type=float, default=50.0, help="station height, m (default 50)")
    demo.add_argument("--gravity", type=float, metavar="M_S2",
                      help="measured local gravity, m/s² (default: WGS84 normal gravity)")
    demo.add_argument("--raw-counts", action="store_true", help="simulate a device reporting 16-bit counts")
    demo.add_argument("--params", metavar="FILE", help="also write the parameter file here")
    demo.set_defaults(func=cmd_demo)

    monitor = sub.add_parser("monitor", help="print decoded samples and parser counters from a device",
                             description="Connect to the configured device and print its decoded "
                             "samples (CSV when piped, a live line on a terminal) and the parser's "
                             "counters, until Ctrl-C.")
    monitor.add_argument("--config", required=True, help="station config: a name in configs/ or a path")
    monitor.add_argument("--samples", type=int, metavar="N", help="stop after N samples")
    monitor.add_argument("--seconds", type=float, metavar="S", help="stop after S seconds")
    monitor.set_defaults(func=cmd_monitor)

    sim = sub.add_parser("sim", help="the simulated MIMU and rate table")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True, metavar="SIM_COMMAND")
    serve = sim_sub.add_parser("serve", help="serve the simulated devices on virtual serial ports",
                               description="Serve the simulated MIMU and rate table over "
                               "pseudo-terminals (or TCP on 127.0.0.1) in real device protocols, and "
                               "print the ports to point the station at. Runs until Ctrl-C.")
    serve.add_argument("--imu-protocol", choices=("xsens", "vectornav", "delimited"), default="xsens")
    serve.add_argument("--table-protocol", choices=("ascii", "grbl"), default="ascii")
    serve.add_argument("--transport", choices=("pty", "tcp"), default="pty")
    serve.add_argument("--speed", type=float, default=1.0,
                       help="1 = real time (default), 10 = ten times faster, 0 = as fast as read")
    serve.add_argument("--rate", type=float, default=250.0, help="sample rate, Hz (default 250)")
    serve.add_argument("--position", type=int, default=1, help="field-18 position of the unit (default 1)")
    serve.add_argument("--seed", type=_seed, default=1)
    serve.add_argument("--latitude", type=float, default=40.0, help="degrees (default 40)")
    serve.add_argument("--height", type=float, default=50.0, help="m (default 50)")
    serve.add_argument("--raw-counts", action="store_true", help="the unit reports 16-bit counts")
    serve.set_defaults(func=cmd_sim_serve)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ValueError as exc:  # ConfigError, ProcedureError, ParameterFileError, bad arguments
        print(f"fieldcal: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fieldcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
