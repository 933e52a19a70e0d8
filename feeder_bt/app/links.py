"""The link matrix: one link of the emulated cell killed one way a cable dies, through the
real drivers, and the same cut as a fault plan on the simulated cell; what each run did.

``emulated`` puts a ``feeder_bt.emulators.linkproxy`` death on one link once parts are
being picked (the camera's at its frame source: ``feeder_bt.emulators.dying_camera``); ``simulated`` gives the simulated cell the same cut as a ``comms_lost`` fault
(the way the driver meets that death: ``LINK_AS``); ``verdict`` says how each run ended.
A run passes when it ends STOPPED, placing again within ``LIMIT_S`` of the link's return,
or in FAULT naming a link, with nothing lost and the emulated world's placements equal to
the cell's count. ``benchmarks/link_matrix.py`` runs the whole matrix; the soak tests a
slice of it.
"""

from __future__ import annotations

import dataclasses
import json
import sqlite3
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import feeder_bt.app.factory as factory
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.emulators.dying_camera import DyingCameraSource
from feeder_bt.emulators.linkproxy import LinkProxy

ROOT = Path(__file__).resolve().parents[2]

LINKS = ("galil", "motion", "position", "io", "notify", "plate", "camera")
HOWS = ("silence", "half_open", "refuse", "drip", "flood", "garbage")
#: how the simulated cell's fault plan gives each death: as the driver meets it. A silent
#: cable, a half-open one and a drip each leave a call waiting out its time-out; a refused
#: connection, a flood (the line cap) and garbage (a reply that does not parse) each end
#: the call at once and the driver drops the link.
LINK_AS = {"silence": "silent", "half_open": "silent", "drip": "silent",
           "refuse": "refused", "flood": "refused", "garbage": "refused"}
#: the simulated cell's device for each link
DEVICE = {"galil": "galil", "motion": "adept", "position": "adept", "io": "adept",
          "notify": "adept", "plate": "plate", "camera": "camera"}
LIMIT_S = 10.0
CUT_AT_S = 28.0          # lenses reach the robot at ~24 s: the cut falls while it picks
AFTER_S = 18.0           # fed after the link is back


def scenario_of(link: str) -> str:
    """Lenses on the belt cell; plates for the plate's link."""
    return str(ROOT / "scenarios" / ("plate_lenses.yaml" if link == "plate" else "lenses.yaml"))


def _proxied(cell: Any, link: str, proxy_to) -> Any:
    """The cell with one link's address moved to a proxy in front of it."""
    if link in ("galil", "plate"):
        spec = getattr(cell, link)
        port = int(spec.url.rsplit(":", 1)[1])
        return dataclasses.replace(cell, **{link: dataclasses.replace(
            spec, url=f"socket://127.0.0.1:{proxy_to(port)}")})
    key = f"{link}_port"
    return dataclasses.replace(cell, adept=dataclasses.replace(
        cell.adept, **{key: proxy_to(getattr(cell.adept, key))}))


def emulated(link: str, how: str, cut_s: float, seed: int = 1, cell: str | None = None,
             at_s: float = CUT_AT_S) -> dict[str, Any]:
    """One run through the real drivers with ``how`` on ``link`` from ``at_s``. The
    camera's link lives in its SDK, not on TCP: its deaths are given at the frame source
    (``feeder_bt.emulators.dying_camera``), in front of the emulated camera."""
    proxies: list[LinkProxy] = []
    cables: list[LinkProxy | DyingCameraSource] = []       # the first is the one cut
    times: dict[str, float] = {}
    real = factory.connect_drivers

    def through_a_proxy(cell_spec, clock, source=None, kind="real"):
        def proxy_to(port: int) -> int:
            proxies.append(LinkProxy(port, seed=seed))
            cables.append(proxies[-1])
            return proxies[-1].port

        def cut() -> None:
            while clock.now() < at_s:
                time.sleep(0.02)
            times["cut"] = clock.now()
            cables[0].cut(how)
            while clock.now() < at_s + cut_s:
                time.sleep(0.02)
            cables[0].restore()
            times["restore"] = clock.now()

        if link == "camera":
            cables.append(DyingCameraSource(source, seed=seed))   # closed with the cell
            hal = real(cell_spec, clock, source=cables[0], kind=kind)
        else:
            hal = real(_proxied(cell_spec, link, proxy_to), clock, source=source, kind=kind)
        threading.Thread(target=cut, daemon=True, name="link-cut").start()
        return hal

    factory.connect_drivers = through_a_proxy
    with tempfile.TemporaryDirectory() as tmp:
        db = str(Path(tmp) / "run.db")
        try:
            report = run_job(RunOptions(scenario=scenario_of(link), cell=cell,
                                        duration=at_s + cut_s + AFTER_S, hal="emulated",
                                        seed=seed, view="none", db=db))
        finally:
            factory.connect_drivers = real
            for p in proxies:
                p.close()
        events = _events(db)
    return verdict(report, events, times.get("cut", at_s), times.get("restore", at_s + cut_s))


def simulated(link: str, how: str, cut_s: float, seed: int = 1, cell: str | None = None,
              at_s: float = CUT_AT_S) -> dict[str, Any]:
    """The same cut as a fault plan on the simulated cell (virtual time)."""
    with tempfile.TemporaryDirectory() as tmp:
        plan = Path(tmp) / "plan.yaml"
        plan.write_text(
            "seed: 1\nscripted:\n"
            f"  - {{at_s: {at_s}, kind: comms_lost, device: {DEVICE[link]}, "
            f"outage_s: {cut_s}, link: {LINK_AS[how]}}}\n")
        db = str(Path(tmp) / "run.db")
        report = run_job(RunOptions(scenario=scenario_of(link), cell=cell,
                                    duration=at_s + cut_s + AFTER_S, hal="sim", fast=True,
                                    seed=seed, view="none", db=db, faults=str(plan)))
        events = _events(db)
    return verdict(report, events, at_s, at_s + cut_s)


def _events(db: str) -> list[tuple[float, str, dict]]:
    with sqlite3.connect(db) as c:
        rows = c.execute("SELECT t, kind, data FROM events ORDER BY t").fetchall()
    return [(t, k, json.loads(d) if d else {}) for t, k, d in rows]


def verdict(report: dict, events: list, t_cut: float, t_restore: float) -> dict[str, Any]:
    """What a run did about the cut: its end, how soon, and whether anything was lost."""
    p = report["parts"]
    after = [(t, k, d) for t, k, d in events if t >= t_cut]
    faults = [t for t, k, d in after if k == "fault"]
    recovered = [t for t, k, d in after if k == "recovered"]
    picked = [t for t, k, d in after if k == "place" and t >= t_restore]
    state = report["state"]
    out: dict[str, Any] = {
        "state": state, "fault": report.get("fault"),
        "end": "FAULT" if state == "FAULT" else "recovered",
        "placed": sum(p["retrieved"].values()), "lost": p["lost"],
        "mismatch": p.get("outcomes"),
        "faults": report["faults"], "reconnects": report.get("reconnects") or {},
        "watchdog_stops": report.get("watchdog_stops"),
        "seen_s": round(faults[0] - t_cut, 2) if faults else None,
        "recovered_after_restore_s": (round(max(recovered[-1] - t_restore, 0.0), 2)
                                      if recovered else None),
        "placing_after_restore_s": round(picked[0] - t_restore, 2) if picked else None,
    }
    if state == "FAULT":
        fault_t = next((t for t, k, d in reversed(after) if k == "state"
                        and d.get("to") == "FAULT"), faults[-1] if faults else None)
        out["fault_after_cut_s"] = round(fault_t - t_cut, 2) if fault_t is not None else None
    out["ok"] = _ok(out)
    return out


def _ok(v: dict[str, Any]) -> bool:
    if v["lost"] or v["mismatch"]:
        return False
    if v["end"] == "FAULT":
        reason = (v["fault"] or "").lower()
        named = any(w in reason for w in ("link", "respond", "connection", "controller"))
        soon = v.get("fault_after_cut_s") is not None
        return named and soon
    # recovered: the cell placed again within the limit of the link's return, or the
    # link's loss was never seen (a short drip the drivers' time-outs ride through)
    return (v["placing_after_restore_s"] is not None
            and v["placing_after_restore_s"] <= LIMIT_S)




def matrix_table(rows: list[dict[str, Any]], cut_s: float) -> str:
    """The matrix's runs of one cut length as a markdown table, links by deaths: how each
    emulated run ended (recovered: seconds from the link's return to the next part placed;
    or FAULT), ``✗`` where it missed the verdict's rules, ``≠ sim`` where the simulated
    cell ended otherwise. docs/real-cell.md quotes it; a test holds the two together."""
    mine = [r for r in rows if r["cut_s"] == cut_s]
    hows = [h for h in HOWS if any(r["how"] == h for r in mine)]
    links = [lk for lk in LINKS if any(r["link"] == lk for r in mine)]
    out = ["| link | " + " | ".join(h.replace("_", "-") for h in hows) + " |",
           "|---|" + "---|" * len(hows)]
    for link in links:
        cells = []
        for how in hows:
            r = next((r for r in mine if r["link"] == link and r["how"] == how), None)
            if r is None:
                cells.append("")
                continue
            e = r["emulated"]
            text = ("FAULT" if e["end"] == "FAULT"
                    else f"{e['placing_after_restore_s']:.1f} s"
                    if e["placing_after_restore_s"] is not None else "recovered")
            text += "" if e["ok"] else " ✗"
            text += "" if r["same_verdict"] else " ≠ sim"
            cells.append(text)
        out.append(f"| {link} | " + " | ".join(cells) + " |")
    return "\n".join(out)
