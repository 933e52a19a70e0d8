"""The run's summary: the report's figures as the lines ``feeder run`` prints at its end (80
columns; faults, misses and alarms in one vocabulary, feeder_bt/core/vocabulary.py),
beside the report they come from."""

from __future__ import annotations

from feeder_bt.core.vocabulary import story_text


def summary(report: dict) -> str:
    """The run's summary (with its faults, misses and alarms: feeder_bt/core/vocabulary.py), lines that fit 80 columns; its parts/min is the report's and the
    live view's last."""
    p = report["parts"]
    how = " (interrupted)" if report.get("interrupted") else ""
    kinds = ", ".join(f"{k} {v}" for k, v in p["retrieved"].items())
    return (f"{report['scenario']}: {report['state']}{how} after {report['feed_seconds']:.0f} s"
            f" ({report['wall_seconds']:.1f} s wall)\n"
            f"  {report['parts_per_minute']:.1f} parts/min, retrieved "
            f"{sum(p['retrieved'].values())} ({kinds})\n"
            f"  located {p['located']}, missed {p['missed']}, lost {p['lost']}"
            + (f", recirculated {p['recirculated_per_placed']:.2f} per placed"
               if p.get("recirculated_per_placed") is not None and not report.get("plate")
               else "")
            + _plate_line(report)
            + _ceiling_line(report) + _fit_line(report) + _robot_time_line(report)
            + _kits_line(report)
            + _robots_line(report) + _outcomes_line(report) + "\n"
            + story_text(report))


def _plate_line(report: dict) -> str:
    """A plate cell's actions (a plate does not recirculate: it flips, feeds, dispenses)."""
    plate = report.get("plate") or {}
    if not plate:
        return ""
    done = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in plate.items()
                     if k != "decisions" and v)
    return f"\n  plate: {done or 'no action'} ({plate.get('decisions', 0)} decisions)"


def _outcomes_line(report: dict) -> str:
    """Placements the world and the cell do not agree on: each a counted mismatch."""
    out = report["parts"].get("outcomes") or {}
    said = [f"{sum(n.values())} placed the cell did not count ({_kinds(n)})"
            for n in [out.get("world_only") or {}] if n]
    said += [f"{sum(n.values())} counted the world never saw placed ({_kinds(n)})"
             for n in [out.get("cell_only") or {}] if n]
    return f"\n  MISMATCH: {'; '.join(said)}" if said else ""


def _kinds(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items())


def _fit_line(report: dict) -> str:
    """The robot model the policies learnt, and how well it predicted the arm's moves."""
    fitted = (report.get("robot_model") or {}).get("fitted") or {}
    res = fitted.get("residual") or {}
    if not res.get("moves"):
        return ""
    return (f"\n  robot fit: x{fitted['time_scale']:.3f} {1000 * fitted['offset_s']:+.0f} ms;"
            f" residual rms {res['rms_ms']:.0f} ms ({res['rms_pct']:.1f} %),"
            f" max {res['max_ms']:.0f} ms")


def _robot_time_line(report: dict) -> str:
    """Where the arm's time went (``robot_time``): what limits the cell at a glance."""
    rt = report.get("robot_time") or {}
    if not rt:
        return ""
    return (f"\n  robot: cycles {rt['cycles_pct']:.1f} %, waiting for parts "
            f"{rt['waiting_pct']:.1f} %, missed {rt['missed_pct']:.1f} %, "
            f"idle {rt['idle_pct']:.1f} %")


def _kits_line(report: dict) -> str:
    """Kits (retrieve.kit or sequence): how many, how fast, against the kit ceiling."""
    from feeder_bt.policy.kits import describe_kits
    k = report.get("kits")
    return f"\n  {describe_kits(k)}" if k else ""


def _robots_line(report: dict) -> str:
    """The part server's distrust: PLACED reports the simulated world did not
    see (not counted as retrieved) and robots cut off; nothing when there was none."""
    ps = report.get("part_server") or {}
    bad = [(ps.get("mismatch", 0), "PLACED the world did not see (not counted)"),
           (ps.get("cut_off", 0), "robot(s) cut off for parts never reported")]
    said = ", ".join(f"{n} {what}" for n, what in bad if n)
    return f"\n  part server: {said}" if said else ""


def _ceiling_line(report: dict) -> str:
    """The ceiling: the lowest of the robot, supply (and inflow) bounds, and how near the
    run came; with an inflow bound or the selection-aware robot rates (a simulated run)
    the bounds get lines of their own (80 columns). The mean cycle's and nearest-first
    selection's rates move with the run's own setting: yardsticks, said so, never a
    ceiling, and the run against them as a ratio."""
    if "ceiling_ppm" not in report:
        return ""
    pct = report["of_ceiling_pct"]
    of = f": {pct:.0f} % of it" if pct is not None else ""
    supply = f"supply {report['supply_bound_ppm']:.1f}"
    if report.get("robot_bound_selection_ppm") is None and "inflow_bound_ppm" not in report:
        return (f"\n  ceiling {report['ceiling_ppm']:.1f} parts/min ({report['ceiling']} bound; "
                f"robot {report['robot_bound_ppm']:.1f}, {supply}){of}")
    robot = f"robot {report['robot_bound_ppm']:.1f}"
    if report.get("robot_bound_selection_ppm") is not None:
        robot += " corner,"
    else:
        robot += ","
    out = (f"\n  ceiling {report['ceiling_ppm']:.1f} parts/min ({report['ceiling']} bound){of}"
           f"\n  bounds: {robot} {supply}")
    if report.get("robot_bound_selection_ppm") is not None:
        mean = report.get("robot_bound_mean_ppm")
        ratio = report.get("of_selection")
        out += ("\n  yardsticks, not bounds:"
                + (f" {mean:.1f} mean cycle," if mean is not None else "")
                + f" {report['robot_bound_selection_ppm']:.1f} nearest-first"
                + (f" (run {ratio:.2f}x)" if ratio is not None else ""))
    if "inflow_bound_ppm" in report:
        out += (f"\n  inflow bound {report['inflow_bound_ppm']:.1f} parts/min (parts reach "
                f"the robot {report['inflow_lag_s']:.1f} s after they come)")
    return out
