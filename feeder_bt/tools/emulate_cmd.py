"""``feeder emulate``: the controller emulators as servers, for driver work without a cell.

``galil`` serves the Galil DMC protocol, ``adept`` the V+ servers (motion, position, I/O,
notify on four consecutive ports), ``cell`` both over one simulated cell, so a robot
picks the parts the conveyors carry. They run until Ctrl-C.
"""

from __future__ import annotations

import argparse
import threading

from ..scenario import load_scenario

DEFAULT_SCENARIO = "scenarios/lenses.yaml"


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("emulate", help="serve the Galil and/or V+ controller emulators "
                                              "on 127.0.0.1, backed by the simulated cell")
    p.add_argument("controller", choices=["galil", "adept", "cell"],
                   help="galil, adept, or cell (both over one simulated cell)")
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO,
                   help=f"scenario whose parts the simulated cell carries (default {DEFAULT_SCENARIO})")
    p.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    p.add_argument("--port", type=int, default=None, metavar="N",
                   help="galil: its port (default 2323); adept: the first of four ports "
                        "(default 1401); cell: the Galil port, V+ from N+1")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--seed", type=int, default=1, help="random seed of the simulated cell")
    p.set_defaults(handler=cmd_emulate)
    return p


def cmd_emulate(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    from ..emulators.adept import AdeptEmulator
    from ..emulators.galil import GalilEmulator
    from ..emulators.plant import Plant

    scenario, cell = load_scenario(args.scenario, args.cell)
    plant = Plant(scenario, cell, args.seed).start()
    servers = []
    try:
        if args.controller in ("galil", "cell"):
            port = 2323 if args.port is None else args.port
            servers.append(GalilEmulator(plant, host=args.host, port=port).start())
            print(f"galil emulator: socket://{args.host}:{servers[-1].port}", flush=True)
        if args.controller in ("adept", "cell"):
            first = 1401 if args.port is None else args.port + (args.controller == "cell")
            names = ("motion", "position", "io", "notify")
            ports = {name: first + i for i, name in enumerate(names)}
            servers.append(AdeptEmulator(plant, host=args.host, ports=ports).start())
            print("adept emulator: " + ", ".join(f"{k} {args.host}:{v}"
                                                   for k, v in servers[-1].ports.items()),
                  flush=True)
        print("Ctrl-C to stop", flush=True)
        (stop or threading.Event()).wait()
    except KeyboardInterrupt:
        pass
    finally:
        for s in servers:
            s.stop()
        plant.stop()
    return 0
