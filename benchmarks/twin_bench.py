"""The twin's round trip (docs/simulator.md, "Twins"): plants unknown to the fit, one event
log of each at one setting, a twin fitted from it, and the twin's parts/min at other
settings against the plant's own mean over seeds; the uncalibrated defaults beside it.

    python benchmarks/twin_bench.py [--plants 5] [--duration 600] [--plant-seeds 11 12 13]
        [--out benchmarks/results/twin.json]
    python benchmarks/twin_bench.py --plate     # the plate cell: 3 plants, 3 settings

Plants: ``feeder_bt.tuning.roundtrip.PLANT_RANGES`` drawn with ``--seed``. The fit's log isthe plant running scenarios/lenses.yaml as shipped for ``--duration`` s (plant i: seed
``--log-seed`` + i). The
settings predicted are five others: a fixed slow belt, a fixed fast belt with a higher
lift, a fixed belt under a low lift, the shortest-cycle pick policy, and the
lenses-and-squares kit. Each plant's truth is its mean over ``--plant-seeds``; the twin's
and the defaults' predictions are means over ``--predict-seeds``. Error: |predicted -
truth| / truth; MAE per setting over the plants, and over everything.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.config import load_scenario  # noqa: E402
from feeder_bt.tuning.roundtrip import Runner, Setting, draw_plants  # noqa: E402
from feeder_bt.tuning.twin import fit_twin  # noqa: E402

LENSES = str(ROOT / "scenarios/lenses.yaml")
KIT = str(ROOT / "scenarios/kits_lenses_squares.yaml")
FIT_SETTING = Setting("as shipped (the fit's log)", LENSES)
SETTINGS = [
    Setting("fixed belt 100 mm/s, lift 40 %", LENSES,
            {"adjust": {"algorithm": "none"}, "present": {"horizontal_mm_s": 100}}),
    Setting("fixed belt 200 mm/s, lift 60 %", LENSES,
            {"adjust": {"algorithm": "none"},
             "present": {"horizontal_mm_s": 200, "incline_pct": 60}}),
    Setting("fixed belt 150 mm/s, lift 25 %", LENSES,
            {"adjust": {"algorithm": "none"},
             "present": {"horizontal_mm_s": 150, "incline_pct": 25}}),
    Setting("shortest-cycle picks", LENSES, {"retrieve": {"policy": "shortest_cycle"}}),
    Setting("kit: 3 lenses + 1 square", KIT),
]
#: ``--plate``: plants from ``PLATE_RANGES``, the log of scenarios/plate_lenses.yaml as
#: shipped, and three other settings of the plate policy and the arm
PLATE = str(ROOT / "scenarios/plate_lenses.yaml")
PLATE_FIT_SETTING = Setting("as shipped (the fit's log)", PLATE)
PLATE_SETTINGS = [
    Setting("dispense below 12 parts", PLATE, {"present": {"plate": {"min_parts": 12}}}),
    Setting("dispense x1, flip x2, feed x1", PLATE,
            {"present": {"plate": {"dispense_reps": 1, "flip_reps": 2, "feed_reps": 1}}}),
    Setting("robot speed 50 %", PLATE, {"retrieve": {"robot_speed_pct": 50}}),
]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=5)
    ap.add_argument("--seed", type=int, default=7, help="draws the plants")
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--plant-seeds", type=int, nargs="+", default=[11, 12, 13])
    ap.add_argument("--predict-seeds", type=int, nargs="+", default=[21, 22])
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--log-seed", type=int, default=31, help="plant i's log: this seed + i")
    ap.add_argument("--plate", action="store_true",
                    help="the plate cell (scenarios/plate_lenses.yaml): 3 plants, 3 settings")
    ap.add_argument("--out", default=None, help="default benchmarks/results/twin.json "
                    "(--plate: twin_plate.json)")
    args = ap.parse_args(argv)
    if args.plate and "--plants" not in (argv if argv is not None else sys.argv):
        args.plants = 3
    args.out = args.out or str(ROOT / "benchmarks/results" /
                               ("twin_plate.json" if args.plate else "twin.json"))
    t_start = time.time()
    fit_setting, others = ((PLATE_FIT_SETTING, PLATE_SETTINGS) if args.plate
                           else (FIT_SETTING, SETTINGS))
    _, cell = load_scenario(fit_setting.scenario)
    runner = Runner(args.duration)
    plants = draw_plants(cell, args.plants, args.seed)
    ps, qs = tuple(args.plant_seeds), tuple(args.predict_seeds)
    settings = [fit_setting, *others]
    defaults = {s.name: runner.ppm(s, None, qs) for s in settings}
    rows = []
    for i, fig in enumerate(plants):
        world = runner.world(fig)
        db = str(runner.tmp / f"plant{i}.db")
        # each plant's log its own seed: one seed's draws are alike across plants
        logged = runner.ppm(fit_setting, world, (args.log_seed + i,), db=db)
        twin = fit_twin([db], cell, rounds=args.rounds,
                        say=lambda s, i=i: print(f"plant {i}: {s}", file=sys.stderr))
        tw = runner.world(twin.figures())
        per = {}
        for s in settings:
            truth = runner.ppm(s, world, ps)
            pred = runner.ppm(s, tw, qs)
            per[s.name] = {"plant": truth, "twin": pred, "defaults": defaults[s.name],
                           "twin_err": abs(pred - truth) / truth,
                           "defaults_err": abs(defaults[s.name] - truth) / truth}
            print(f"plant {i} {s.name}: plant {truth:.1f} twin {pred:.1f} "
                  f"defaults {defaults[s.name]:.1f}", file=sys.stderr)
        rows.append({"plant": fig, "logged_ppm": logged,
                     "fitted": {k: {"value": e.value, "sd": e.sd, "fixed": e.fixed,
                                    "fixed_by": e.fixed_by}
                                for k, e in twin.estimates.items()},
                     "settings": per})
        _write(args, settings, rows, t_start, ps, qs)      # each plant as it is done
    _write(args, settings, rows, t_start, ps, qs, final=True)
    return 0


def _write(args: argparse.Namespace, settings: list[Setting], rows: list[dict],
           t_start: float, ps: tuple[int, ...], qs: tuple[int, ...],
           final: bool = False) -> None:
    """The JSON so far (plants done), and with ``final`` the table on standard output."""
    summary = {}
    for s in settings:
        summary[s.name] = {
            "twin_mae_pct": 100 * statistics.mean(r["settings"][s.name]["twin_err"] for r in rows),
            "defaults_mae_pct": 100 * statistics.mean(r["settings"][s.name]["defaults_err"]
                                                      for r in rows)}
    others = [s.name for s in settings[1:]]
    overall = {k: statistics.mean(summary[n][k] for n in others)
               for k in ("twin_mae_pct", "defaults_mae_pct")}
    out = {"benchmark": "twin round trip" + (", plate" if args.plate else ""),
           "scenario": str(Path(settings[0].scenario).relative_to(ROOT)),
           "plants": args.plants, "plants_done": len(rows),
           "seed": args.seed,
           "duration_s": args.duration, "plant_seeds": ps, "predict_seeds": qs,
           "rounds": args.rounds, "settings": summary, "other_settings_mae_pct": overall,
           "rows": rows, "wall_s": time.time() - t_start, "python": platform.python_version()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    if not final:
        return
    for name, v in summary.items():
        print(f"{name:34s} twin {v['twin_mae_pct']:5.1f} %  defaults {v['defaults_mae_pct']:5.1f} %")
    print(f"{f'{len(others)} other settings':34s} twin {overall['twin_mae_pct']:5.1f} %  "
          f"defaults {overall['defaults_mae_pct']:5.1f} %")
    print(f"json: {args.out}")


if __name__ == "__main__":
    sys.exit(main())
