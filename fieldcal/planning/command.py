"""``fieldcal plan``: the least-operator-time procedure for a unit's noise and a target σ."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

# numpy, yaml and the model are imported by the functions that use them: add_plan_parser is
# called whenever the command line is built, and `fieldcal --help` must stay light (issue 12).

GROUPS = {"bias": range(0, 3), "scale": range(3, 6), "misalignment": range(6, 9)}
MAX_HANDLING_S = 3600.0  # --place-s and --settle-s: an hour per position is no station's
# A planned σ this many times field-18's leaves its parameter undetermined (the TUI's plan view
# uses the same factor against the target): such a plan is refused, not written.
UNDETERMINED = 100.0


def add_plan_parser(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "plan", help="plan the shortest procedure that meets a target accuracy",
        description="From the device config's triad noise, the table's top rate and an operator "
        "model, find the positions, dwell and rate steps with the least operator time whose "
        "Cramér-Rao bound meets the target for every parameter, and write it as a procedure file.")
    parser.add_argument("--config", required=True, help="station config: a name in configs/ or a path")
    parser.add_argument("--target", default="field-18", metavar="TARGET",
                        help="field-18 (default): every σ no worse than the 18 × 200 s procedure's, "
                        "biases judged against the bias at the end of the calibration (the value the "
                        "unit is used with); field-18,TRIAD.GROUP=σ,... tightens or relaxes groups of "
                        "it; or TRIAD.GROUP=σ,... alone (biases as turn-on constants), in operator "
                        "units, GROUP bias (mg, °/h), scale (1) or misalignment (mrad), e.g. "
                        "accelerometer.bias=0.06,gyroscope.scale=2e-5")
    parser.add_argument("--slack", type=float, default=None, metavar="FRACTION",
                        help="allow σ up to (1 + FRACTION) × the target (default "
                        f"{FIELD_18_SLACK:g} for a field-18 target, 0 for σ targets alone)")
    parser.add_argument("--margin", type=float, default=0.0, metavar="FRACTION",
                        help="plan every bound this fraction under the target (with its slack), "
                        "for the scatter of the errors a check measures: a Monte Carlo's RMS error "
                        "over N runs scatters by about 1/√(2N) (default 0)")
    parser.add_argument("--thermal-target", metavar="TARGET",
                        help="TRIAD.bias_drift=σ (mg/K, °/h/K) or TRIAD.scale_drift=σ (ppm/K) pairs: "
                        "say how far the unit's temperature must change during the planned run for the "
                        "joint thermal fit to reach them (a steady warm-up assumed), e.g. "
                        "accelerometer.bias_drift=0.02,gyroscope.bias_drift=5")
    parser.add_argument("--out", required=True, metavar="FILE.yaml", help="where the procedure goes")
    parser.add_argument("--force", action="store_true", help="replace the --out file if it exists "
                        "(never the --config nor a procedure the plan reads)")
    parser.add_argument("--place-s", type=float, metavar="S",
                        help="seconds to carry and place the unit (default: the headless operator's)")
    parser.add_argument("--settle-s", type=float, metavar="S",
                        help="seconds from placed to the dwell's start (default: the engine's "
                        "stillness window and orientation check)")
    parser.add_argument("--corners", action="store_true",
                        help="offer corner positions too (gravity along a body diagonal, the unit "
                        "held on a corner): for the paper's unit they save about 1 %% of the time "
                        "and double the search's")
    parser.set_defaults(func=cmd_plan)
    return parser


def station_models(config):
    """What the station knows of each triad of the configured device (the simulator's truth for
    the simulated one, which is what a headless run solves with)."""
    if config.device.protocol == "sim":
        from drivers.sim.device import paper_mimu
        from fieldcal.solvers.solve import models_from_truth
        sim = config.device.sim
        return models_from_truth(paper_mimu(sim.raw_counts, sim.flicker_tau_max_s))
    from fieldcal.run.livedevice import LiveDevice
    return dict(LiveDevice.from_config(config).models)


def parse_targets(text: str, models) -> dict[str, np.ndarray]:
    """``TRIAD.GROUP=σ`` pairs in operator units to per-parameter σ in solver units."""
    import numpy as np

    from fieldcal.model import PARAM_NAMES
    from fieldcal.units import display_scale

    from fieldcal.planning.targets import sigma_pairs

    targets = {name: np.full(len(PARAM_NAMES), np.inf) for name in models}
    for triad, group, sigma in sigma_pairs(text, models, GROUPS, "--target"):
        model = models[triad]
        for j in GROUPS[group]:
            targets[triad][j] = sigma / display_scale(model.kind, model.output_unit, j)
    if all(np.all(np.isinf(t)) for t in targets.values()):
        raise ValueError("--target: no σ given; use field-18 or TRIAD.GROUP=σ pairs")
    return targets


def resolve_targets(text: str, models, ref_sigmas) -> dict[str, np.ndarray]:
    """``field-18`` (field-18's σ, ``ref_sigmas``) with any ``TRIAD.GROUP=σ`` after it replacing
    its groups, or ``TRIAD.GROUP=σ`` pairs alone."""
    import numpy as np

    if not judged_at_end(text):
        return parse_targets(text, models)
    targets = {name: np.array(sigmas, dtype=float) for name, sigmas in ref_sigmas.items()}
    rest = text.partition(",")[2]
    if rest.strip():
        for name, given in parse_targets(rest, models).items():
            targets[name] = np.where(np.isfinite(given), given, targets[name])
    return targets


# A field-18 target's default allowance: field-18's bias at the end of the calibration comes from
# the most recent of its 85 minutes of averages, and a procedure of a fifth of that time cannot
# match it to the percent for the gyro (the bound's floor is about 1.045× field-18's for the
# paper's unit, at any flicker cut-off): "as good as field-18" is within 10 %, as issue 22 states.
FIELD_18_SLACK = 0.10


def default_slack(args) -> float:
    """--slack as given, else FIELD_18_SLACK for a field-18 target and 0 for σ targets alone."""
    if args.slack is not None:
        return args.slack
    return FIELD_18_SLACK if judged_at_end(args.target) else 0.0


def judged_at_end(text: str) -> bool:
    """A target based on field-18 judges biases against the bias at the end of the calibration
    (DESIGN 12); a list of TRIAD.GROUP=σ alone keeps the turn-on constants' σ it always meant."""
    return text.partition(",")[0].strip() == "field-18"


def operator_targets(models, limits, at_end: bool = False) -> dict[str, dict[str, float]]:
    """The finite σ limits per triad and parameter in operator units (4 significant digits), as a
    planned procedure carries them for the TUI to show against the σ reached. ``at_end``: the
    biases' limits are against the bias at the end of the calibration, which the TUI's σ of the
    turn-on constant does not measure, so they are left out rather than shown as met."""
    import numpy as np

    from fieldcal.model import PARAM_NAMES
    from fieldcal.units import display_scale

    out = {}
    for name, model in models.items():
        row = {p: float(f"{limits[name][j] * display_scale(model.kind, model.output_unit, j):.4g}")
               for j, p in enumerate(PARAM_NAMES) if np.isfinite(limits[name][j])
               and not (at_end and j in GROUPS["bias"])}
        if row:
            out[name] = row
    return out


def procedure_yaml(plan, name: str, title: str, operator, target: str | None = None,
                   targets: dict | None = None) -> str:
    import yaml

    design = plan.design
    doc = {"name": name, "title": title, "dwell_s": float(design.dwell_s), "adaptive_dwell": True,
           "any_order": True, "rate_step": {"rate_deg_s": float(design.rate_deg_s), "turns": int(design.turns),
                         "ramp_s": round(operator.ramp_s(design.rate_deg_s), 3),
                         "settle_s": float(operator.rate_settle_s)},
           "positions": [{"id": i, "description": c.name, **c.fields,
                          **({} if design.turns_at(i - 1) else {"rate_step": "none"})}
                         for i, c in enumerate(plan.positions, start=1)]}
    if targets:
        doc["targets"] = targets
    head = ("# Planned by `fieldcal plan`: the least operator time whose Cramér-Rao bound meets the\n"
            "# target for every parameter. An ordinary procedure file: edit, validate and run it.\n"
            "# adaptive_dwell: each dwell ends once it holds the planned information at the noise\n"
            "# the unit shows (longer if noisier than its model, never below the minimum dwell).\n"
            "# any_order: place the positions in any order; the station recognises each from gravity.\n"
            "# targets: the σ each parameter must reach, in the units `fieldcal plan` prints them.\n")
    if target is not None:  # in full, whether or not the title has room for it
        head += "# target: " + " ".join(target.split()) + "\n"
    return head + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, width=100)


def plan_title(device: str, target: str, slack: float) -> str:
    """The procedure's title: the device and the target, within what a procedure file allows for a
    title (a long TRIAD.GROUP=σ list does not fit; the σ are in the table the command prints)."""
    from fieldcal.procedure.positions import _TEXT_LIMIT

    extra = f" (+{slack:.0%})" if slack else ""
    title = f"Planned for {device}, target {target}{extra}"
    if len(title) > _TEXT_LIMIT:
        count = len([item for item in target.split(",") if item.strip()])
        title = f"Planned for {device}, target: {count} σ limits{extra}"
    if len(title) > _TEXT_LIMIT:
        title = title[:_TEXT_LIMIT - 1] + "…"
    return title


def plan_inputs(args) -> list[str]:
    """The files ``plan`` reads: its config (a path or a shipped name), the procedure it plans
    from; its --out is never one of them, even with --force."""
    from fieldcal.paths import find_named

    names = [find_named(args.config, "config"), find_named("field-18", "procedure")]
    return [str(n) for n in names if n is not None]


def cmd_plan(args) -> int:
    import numpy as np

    from fieldcal.config import load_config
    from fieldcal.model import PARAM_NAMES
    from fieldcal.planning.design import Design, OperatorModel, bound_sigmas, operator_time
    from fieldcal.planning.search import Plan, Planner, candidates
    from fieldcal.procedure.positions import load_procedure, parse_procedure
    from fieldcal.units import display_scale, param_unit

    args.slack = default_slack(args)
    check_plan_options(args)
    config = load_config(args.config)
    models = station_models(config)
    station, rate_hz = config.station, config.device.rate_hz
    operator = OperatorModel(**{k: v for k, v in (("place_s", args.place_s), ("settle_s", args.settle_s))
                                if v is not None})
    max_rate = config.table.max_rate_deg_s if config.table is not None else 20.0
    reference = load_procedure("field-18")
    step = reference.rate_step
    ref_design = Design(tuple(p.attitude for p in reference.positions), reference.dwell_s,
                        step.rate_deg_s, step.turns)
    at_end = judged_at_end(args.target)
    ref_sigmas = bound_sigmas(ref_design, operator, models, station, rate_hz, bias_at_end=at_end)
    ref_seconds = operator_time(ref_design, operator)
    targets = resolve_targets(args.target, models, ref_sigmas)
    thermal_targets = None
    if args.thermal_target is not None:  # before the search: a typo is told in a second, not minutes
        from fieldcal.planning.thermal_span import parse_thermal_targets
        thermal_targets = parse_thermal_targets(args.thermal_target, models)
    limits = {n: t * (1 + args.slack) for n, t in targets.items()}
    planned_to = {n: t / (1 + args.margin) for n, t in limits.items()}  # what the search must reach
    print(f"planning for {config.device.name}: table up to {max_rate:g} °/s, operator "
          f"{operator.place_s:g} s to place + {operator.settle_s:g} s to settle per position",
          file=sys.stderr, flush=True)
    pool = candidates(reference.positions, corners=args.corners)
    planner = Planner(models, station, rate_hz, operator, planned_to, max_rate, bias_at_end=at_end)
    plan = planner.search(pool)
    if at_end:  # the user's terms: a rate step only where the target needs it
        plan = planner.turn_where_it_pays(plan)
    meets_reference = all(np.all(ref_sigmas[n] <= t) for n, t in planned_to.items())
    if plan.seconds >= ref_seconds and meets_reference:
        # Nothing shorter meets the target (a tight one against field-18's own σ, whose long span
        # averages the bias instability best): field-18 itself, with the adaptive dwell.
        print("no procedure shorter than field-18 meets the target: writing field-18's positions",
              file=sys.stderr)
        chosen = tuple(next(c for c in pool if np.allclose(c.attitude, p.attitude))
                       for p in reference.positions)
        plan = Plan(chosen, ref_design, ref_seconds, ref_sigmas)
    elif plan.seconds >= ref_seconds:  # field-18 misses the target too: longer is the price, said
        untightened = all(np.all(ref_sigmas[n] <= t) for n, t in limits.items())
        why = (f"; field-18 meets it without the {args.margin:.0%} --margin (--slack {args.margin:g} "
               f"plans to field-18's σ)" if args.margin and untightened else "")
        print(f"no procedure shorter than field-18 meets the target{' with --margin' * bool(args.margin)}: "
              f"this plan takes {plan.seconds / ref_seconds:.2f}× field-18's time{why}", file=sys.stderr)
    refuse_undetermined(plan.sigmas, ref_sigmas, models)
    out = Path(args.out)
    text = procedure_yaml(plan, out.stem, plan_title(config.device.name, args.target, args.slack),
                          operator, args.target + (f" (+{args.slack:.0%})" if args.slack else ""),
                          operator_targets(models, limits, at_end))
    parse_procedure(text, out.name)  # what is written loads as an ordinary procedure
    from fieldcal.atomic import write_atomically
    write_atomically(out, text.encode("utf-8"), overwrite=args.force, hint="give --force to replace it",
                     inputs=plan_inputs(args))
    design = plan.design
    turning = sum(design.turns_at(i) for i in range(len(plan.positions)))
    where = "" if turning == len(plan.positions) else f" at {turning} of them"
    print(f"{len(plan.positions)} positions, {design.dwell_s:g} s dwell, rate steps{where} ±{design.rate_deg_s:g} °/s "
          f"× {design.turns} turn{'s' * (design.turns > 1)}: operator time {plan.seconds / 60:.1f} min "
          f"against field-18's {ref_seconds / 60:.1f} min ({plan.seconds / ref_seconds:.2f}×); written to {out}")
    if args.margin:
        print(f"every bound planned {args.margin:.0%} under its target σ (--margin)")
    print("| triad | parameter | unit | target σ | planned σ | planned/target | field-18 σ |")
    print("|---|---|---|---|---|---|---|")
    for name, model in models.items():
        for j, pname in enumerate(PARAM_NAMES):
            scale = display_scale(model.kind, model.output_unit, j)
            target = limits[name][j]  # the σ enforced: the target with its slack
            shown = "-" if np.isinf(target) else f"{target * scale:.3g}"
            ratio = "-" if np.isinf(target) else f"{plan.sigmas[name][j] / target:.3f}"
            shown_name = f"{pname} at end" if at_end and j in GROUPS["bias"] else pname
            print(f"| {name} | {shown_name} | {param_unit(model.kind, model.output_unit, j)} | {shown} | "
                  f"{plan.sigmas[name][j] * scale:.3g} | {ratio} | {ref_sigmas[name][j] * scale:.3g} |")
    if at_end:
        print_turn_on_biases(plan, ref_design, operator, models, station, rate_hz)
    if thermal_targets is not None:
        from fieldcal.planning.thermal_span import drift_sigmas_per_kelvin, thermal_lines
        from fieldcal.solvers.solve import THERMAL_MIN_SPAN_K
        per_kelvin = drift_sigmas_per_kelvin(plan.design, operator, models, station, rate_hz)
        print("\n".join(thermal_lines(per_kelvin, thermal_targets, models, THERMAL_MIN_SPAN_K)))
    print_time_and_floor(plan, ref_design, ref_seconds, operator, models, planned_to, ref_sigmas, at_end)
    return 0


def print_turn_on_biases(plan, ref_design, operator, models, station, rate_hz) -> None:
    """The gyroscopes' turn-on bias σ, planned and field-18's: solved and reported, but not part
    of the time target, and the operator is told why in one line."""
    from fieldcal.model import ANGULAR_RATE
    from fieldcal.planning.design import bound_sigmas
    from fieldcal.units import display_scale, param_unit

    gyros = {n: m for n, m in models.items() if m.kind == ANGULAR_RATE}
    if not gyros:
        return
    planned = bound_sigmas(plan.design, operator, gyros, station, rate_hz)
    reference = bound_sigmas(ref_design, operator, gyros, station, rate_hz)
    for name, model in gyros.items():
        scale, unit = display_scale(model.kind, model.output_unit, 0), param_unit(model.kind, model.output_unit, 0)
        print(f"{name} turn-on bias σ {', '.join(f'{s * scale:.3g}' for s in planned[name][:3])} {unit} "
              f"(field-18: {', '.join(f'{s * scale:.3g}' for s in reference[name][:3])}): solved and reported, "
              "not part of the time target, since a MEMS gyro's turn-on bias does not repeat from one "
              "power-up to the next and every INS re-estimates it at alignment")


def check_plan_options(args) -> None:
    """Every numeric option finite and in its range, before the search (which takes minutes):
    one line naming the option, its range and the value."""
    import math

    if not (math.isfinite(args.slack) and args.slack >= 0):
        raise ValueError(f"--slack: expected a finite fraction >= 0, got {args.slack!r}")
    if not 0 <= args.margin < 1:
        raise ValueError(f"--margin: expected a fraction from 0 to below 1, got {args.margin!r}")
    for option, value in (("--place-s", args.place_s), ("--settle-s", args.settle_s)):
        if value is not None and not 0 <= value <= MAX_HANDLING_S:
            raise ValueError(f"{option}: expected seconds from 0 to {MAX_HANDLING_S:g}, got {value!r}")


def refuse_undetermined(sigmas, ref_sigmas, models) -> None:
    """A plan whose bound leaves a parameter undetermined (σ beyond UNDETERMINED × field-18's,
    or not finite) is refused in one line naming the worst: a procedure file that cannot
    calibrate its unit must not be written, whatever the target allowed."""
    import numpy as np

    from fieldcal.model import PARAM_NAMES
    from fieldcal.units import display_scale, param_unit

    worst = None
    for name, model in models.items():
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.isfinite(sigmas[name]), sigmas[name] / ref_sigmas[name], np.inf)
        j = int(np.argmax(ratio))
        if not ratio[j] <= UNDETERMINED and (worst is None or ratio[j] > worst[0]):
            worst = (float(ratio[j]), name, j, model)
    if worst is not None:
        ratio, name, j, model = worst
        scale = display_scale(model.kind, model.output_unit, j)
        raise ValueError(f"plan: the shortest procedure that meets the target leaves {name} {PARAM_NAMES[j]} "
                         f"undetermined (σ {sigmas[name][j] * scale:.3g} {param_unit(model.kind, model.output_unit, j)}, "
                         f"{ratio:.3g}× field-18's): give a target for it, or less --slack; nothing was written")


def bias_spans(models, limits) -> dict[str, float]:
    """Per triad with a bias target: the shortest averaging span (s) whose bias floor meets it."""
    import numpy as np

    from fieldcal.planning.design import shortest_span

    spans = {}
    for name, model in models.items():
        wanted = [limits[name][j] / abs(model.sensitivity[j, j]) for j in GROUPS["bias"]
                  if np.isfinite(limits[name][j])]
        if wanted:
            spans[name] = shortest_span(model.noise, min(wanted))
    return spans


SHARES_OF_FIELD_18 = (1 / 3, 1 / 5)  # issue 13's "1/3 of field-18's time" and its aim, 1/5


def best_bias_ratios(models, ref_sigmas, seconds: float) -> dict[str, float]:
    """Per triad, the least worst-axis bias σ / field-18's σ that any procedure of ``seconds``
    operator time can reach: its averages all lie within that span, so none beats the floor."""
    import numpy as np

    from fieldcal.planning.design import bias_floor

    out = {}
    for name, model in models.items():
        bias = list(GROUPS["bias"])  # solver units: the floor (input units) × the axis's sensitivity
        floor = bias_floor(model.noise, seconds) * np.abs(np.diag(model.sensitivity))
        out[name] = float(np.max(floor / ref_sigmas[name][bias]))
    return out


def print_time_and_floor(plan, ref_design, ref_seconds, operator, models, limits, ref_sigmas,
                         at_end: bool = False) -> None:
    """Where the time goes, the least time any procedure needs for the bias targets, and the best
    bias σ any procedure reaches in a third and a fifth of field-18's time (floors of the turn-on
    constants: not said when the biases are judged at the end of the calibration)."""
    from fieldcal.planning.design import time_breakdown

    print()
    for label, design, seconds in (("planned", plan.design, plan.seconds),
                                   ("field-18", ref_design, ref_seconds)):
        parts = ", ".join(f"{k} {v / 60:.1f}" for k, v in time_breakdown(design, operator).items())
        print(f"{label}: {seconds / 60:.1f} min = {parts} min")
    if at_end:
        return
    for name, span in bias_spans(models, limits).items():
        print(f"{name}: its bias σ as planned needs averaging over at least {span / 60:.1f} min "
              f"({span / ref_seconds:.2f}× field-18's time) whatever the positions and dwells: its "
              "bias instability is correlated over minutes, so the run's span, not each dwell, sets it")
    for share in SHARES_OF_FIELD_18:
        best = best_bias_ratios(models, ref_sigmas, share * ref_seconds)
        print(f"in 1/{round(1 / share)} of field-18's time ({share * ref_seconds / 60:.1f} min) no procedure "
              "gets its biases below " + ", ".join(f"{r:.2f}× field-18's σ ({n})" for n, r in best.items()))
