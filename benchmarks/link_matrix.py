"""The fault proxy's matrix: every link of the emulated cell, killed every way a cable dies,
through the real drivers; the same plan in the simulator; the verdicts side by side.

    python benchmarks/link_matrix.py --out benchmarks/results/link_matrix.json
    python benchmarks/link_matrix.py --links galil --hows silence --more-cuts ""  # one run

Each emulated run (``--hal emulated``, real time) feeds lenses (plates for the ``plate``
link) and, once parts are being picked, puts a ``feeder_bt.emulators.linkproxy`` death on
one link for the cut's seconds (the camera's, whose link lives in its SDK, at the frame
source: ``feeder_bt.emulators.dying_camera``). A run passes when it ends STOPPED having recovered, or in
FAULT naming a link, within ``LIMIT_S`` of the cut's end (of its start for a FAULT), with
nothing lost and the emulated world's placements equal to the cell's count. The same cut
is then run on the simulated cell as a fault plan (``comms_lost``, the way the driver sees
that death: ``LINK_AS``), and the two verdicts (recovered or FAULT) must agree.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.app.links import (  # noqa: E402
    HOWS,
    LIMIT_S,
    LINKS,
    emulated,
    matrix_table,
    simulated,
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--links", default=",".join(LINKS))
    ap.add_argument("--hows", default=",".join(HOWS))
    ap.add_argument("--cuts", default="4", help="seconds each link stays dead")
    ap.add_argument("--more-cuts", default="1.5,10",
                    help="also these, for silence, half-open and refuse on --more-links")
    ap.add_argument("--more-links", default="galil,motion,camera")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    rows = []
    started = time.time()
    for link in a.links.split(","):
        for how in a.hows.split(","):
            cuts = a.cuts.split(",")
            if how in ("silence", "half_open", "refuse") and link in a.more_links.split(","):
                cuts += [c for c in a.more_cuts.split(",") if c]
            for cut_s in sorted({float(c) for c in cuts}):
                t0 = time.time()
                emu = emulated(link, how, cut_s, a.seed)
                sim = simulated(link, how, cut_s, a.seed)
                row = {"link": link, "how": how, "cut_s": cut_s, "emulated": emu,
                       "simulated": sim, "same_verdict": emu["end"] == sim["end"],
                       "wall_s": round(time.time() - t0, 1)}
                rows.append(row)
                print(f"{link:9s} {how:9s} {cut_s:4g} s  emulated {emu['end']:9s} "
                      f"{'ok' if emu['ok'] else 'FAIL':4s} placed {emu['placed']:3d} lost "
                      f"{emu['lost']}  simulated {sim['end']:9s}  "
                      f"{'same' if row['same_verdict'] else 'DIFFERENT'}"
                      f"{'  ' + (emu['fault'] or '')[:70] if emu['end'] == 'FAULT' else ''}",
                      flush=True)
    summary = {"runs": len(rows), "ok": sum(r["emulated"]["ok"] for r in rows),
               "same_verdict": sum(r["same_verdict"] for r in rows),
               "limit_s": LIMIT_S, "wall_s": round(time.time() - started)}
    for cut_s in sorted({r["cut_s"] for r in rows}):
        print(f"\n{cut_s:g} s\n" + matrix_table(rows, cut_s))
    print(f"{summary['ok']} of {summary['runs']} runs ok; {summary['same_verdict']} with the "
          "simulator's verdict")
    if a.out:
        Path(a.out).write_text(json.dumps({"summary": summary, "rows": rows}, indent=1) + "\n")
    return 0 if summary["ok"] == summary["runs"] == summary["same_verdict"] else 1


if __name__ == "__main__":
    sys.exit(main())
