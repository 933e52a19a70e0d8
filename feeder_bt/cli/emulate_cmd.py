"""``feeder emulate``: the controller emulators as servers, for driver work without a cell.

``galil`` serves the Galil DMC protocol, ``adept`` the V+ servers (motion, position, I/O,
notify on four consecutive ports), ``cell`` both and the camera (``GRAB`` on the port after
the V+ ones: ``camera.source: emulated-camera://HOST:PORT``) over one simulated cell, so a
robot picks the parts the conveyors carry.

Standard input carries the person's actions on the cell, one a line, each answered with
one line on standard output (``feeder_bt.emulators.operator``; ``help`` lists them): so
``feeder commission`` in another process can be rehearsed with a person's hands. The end
of standard input (none in CI) leaves the emulators running; only Ctrl-C or SIGTERM stops
them.
"""

from __future__ import annotations

import argparse
import inspect
import signal
import sys
import threading
from typing import TextIO

from feeder_bt.config import load_scenario

DEFAULT_SCENARIO = "scenarios/lenses.yaml"
GRIP_SYNC_S = 0.02           # how often the grip sensor follows the vacuum and a held part


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("emulate", help="serve the Galil and/or V+ controller emulators "
                                              "on 127.0.0.1, backed by the simulated cell; "
                                              "the person's actions on standard input")
    p.add_argument("controller", choices=["galil", "adept", "cell", "plate"],
                   help="galil, adept, or cell (both and the camera over one simulated cell); "
                        "plate: an AnyFeeder over a simulated plate")
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO,
                   help=f"scenario whose parts the simulated cell carries (default {DEFAULT_SCENARIO})")
    p.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    p.add_argument("--port", type=int, default=None, metavar="N",
                   help="galil: its port (default 2323); adept: the first of four ports "
                        "(default 1401); cell: the Galil port, V+ from N+1, camera N+5")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--seed", type=int, default=1, help="random seed of the simulated cell")
    p.add_argument("--robot-error", type=float, nargs=3, default=None,
                   metavar=("DX", "DY", "DEG"),
                   help="the simulated robot's true base differs from the cell file's by this "
                        "(mm, mm, deg): what `feeder commission adept` must measure")
    p.add_argument("--servo-error-at", type=int, default=None, metavar="N",
                   help="plate: the Nth action ends with a servo error (m13)")
    p.add_argument("--echo", action="store_true",
                   help="plate: echo each command line before the motor codes, as some "
                        "feeders do")
    p.add_argument("--motor-gap", type=float, default=0.0, metavar="S",
                   help="plate: motor 2 reports this long after motor 1 (default 0)")
    p.add_argument("--late-error-at", type=int, default=None, metavar="N",
                   help="plate: in the Nth action motor 2 never starts and reports m28 "
                        "(no sync) after motor 1 is done")
    p.add_argument("--camera-delay-ms", type=float, default=0.0, metavar="MS",
                   help="the emulated camera exposes this long after its trigger (default 0): "
                        "what the timing step of `feeder commission camera` must find")
    p.set_defaults(handler=cmd_emulate)
    return p


def true_base(cell, error: list[float] | None) -> tuple[float, float, float] | None:
    """The robot base's true pose: the cell file's plus ``--robot-error``."""
    if error is None:
        return None
    bx, by = cell.robot.base_mm
    return (bx + error[0], by + error[1], float(getattr(cell.robot, "base_deg", 0.0)) + error[2])


def _adept(plant, host: str, ports: dict[str, int], base):
    from feeder_bt.emulators.adept import AdeptEmulator
    kwargs = {}
    if base is not None:
        if "true_base" not in inspect.signature(AdeptEmulator).parameters:
            raise SystemExit("emulate: --robot-error needs a V+ emulator with a true base "
                             "(AdeptEmulator(true_base=...), FRAME_SPEC)")
        kwargs["true_base"] = base
    return AdeptEmulator(plant, host=host, ports=ports, **kwargs).start()


def read_actions(operator, stdin: TextIO, out: TextIO, lock: threading.Lock) -> None:
    """The person's actions, a line each, until the end of input (then nothing: the
    emulators serve on)."""
    for line in stdin:
        answer = operator.handle(line)
        if answer is not None:
            with lock:
                print(answer, file=out, flush=True)
    with lock:
        print("end of actions (standard input closed); serving on until Ctrl-C", file=out,
              flush=True)


def cmd_emulate(args: argparse.Namespace, stop: threading.Event | None = None,
                stdin: TextIO | None = None) -> int:
    from feeder_bt.cli.commission.camera import cell_target
    from feeder_bt.emulators.camera_server import CameraScene, CameraServer
    from feeder_bt.emulators.galil.emulator import GalilEmulator
    from feeder_bt.emulators.operator import Operator
    from feeder_bt.sim.realtime import Plant

    if args.controller == "plate":
        return emulate_plate(args, stop, stdin)
    scenario, cell = load_scenario(args.scenario, args.cell)
    plant = Plant(scenario, cell, args.seed).start()
    stop = stop or threading.Event()
    servers: list = []
    galil = adept = scene = None
    out_lock = threading.Lock()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        if args.controller in ("galil", "cell"):
            port = 2323 if args.port is None else args.port
            galil = GalilEmulator(plant, host=args.host, port=port).start()
            servers.append(galil)
            print(f"galil emulator: socket://{args.host}:{galil.port}", flush=True)
        if args.controller in ("adept", "cell"):
            first = 1401 if args.port is None else args.port + (args.controller == "cell")
            names = ("motion", "position", "io", "notify")
            ports = {name: first + i for i, name in enumerate(names)}
            adept = _adept(plant, args.host, ports,
                           true_base(cell, getattr(args, "robot_error", None)))
            servers.append(adept)
            print("adept emulator: " + ", ".join(f"{k} {args.host}:{v}"
                                                   for k, v in adept.ports.items()), flush=True)
        if args.controller == "cell":
            scene = CameraScene(plant, getattr(args, "camera_delay_ms", 0.0) / 1000.0, args.seed)
            cam_port = 0 if args.port is None else args.port + 5
            camera = CameraServer(scene, args.host, cam_port).start()
            servers.append(camera)
            print(f"camera emulator: emulated-camera://{args.host}:{camera.port}", flush=True)
        operator = Operator(plant, galil, adept, scene, cell_target(cell))

        def grip_loop() -> None:
            while not stop.wait(GRIP_SYNC_S):
                operator.sync_grip()
        threading.Thread(target=grip_loop, name="grip-sensor", daemon=True).start()
        print("actions on standard input ('help'); Ctrl-C to stop", flush=True)
        threading.Thread(target=read_actions, args=(operator, stdin or sys.stdin, sys.stdout,
                                                    out_lock),
                         name="operator", daemon=True).start()
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        for s in servers:
            s.stop()
        plant.stop()
    return 0


PLATE_SCENARIO = "scenarios/plate_lenses.yaml"


def emulate_plate(args: argparse.Namespace, stop: threading.Event | None = None,
                  stdin: TextIO | None = None) -> int:
    """``feeder emulate plate``: the AnyFeeder emulator over a simulated plate, its bytes
    raw on ``--port`` (a serial-to-Ethernet bridge), until Ctrl-C or SIGTERM; the person's
    eyes on standard input (``look``)."""
    from feeder_bt.emulators.anyfeeder import AnyFeederEmulator, PlateOperator
    from feeder_bt.sim.realtime import Plant

    path = PLATE_SCENARIO if args.scenario == DEFAULT_SCENARIO else args.scenario
    scenario, cell = load_scenario(path, args.cell)
    if cell.presentation != "plate":
        raise SystemExit(f"emulate plate: {cell.path}: not a plate cell "
                         "(presentation: plate); try cells/sim_plate.yaml")
    stop = stop or threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    plant = Plant(scenario, cell, args.seed).start()
    emu = AnyFeederEmulator(plant, host=args.host, port=args.port or 0,
                            servo_error_at=getattr(args, "servo_error_at", None),
                            echo=getattr(args, "echo", False),
                            motor_gap_s=getattr(args, "motor_gap", 0.0),
                            late_error_at=getattr(args, "late_error_at", None)).start()
    print(f"anyfeeder emulator: socket://{args.host}:{emu.port}"
          f"{' (echo)' if emu.echo else ''}", flush=True)
    print("actions on standard input ('help'); Ctrl-C to stop", flush=True)
    threading.Thread(target=read_actions, args=(PlateOperator(emu), stdin or sys.stdin,
                                                sys.stdout, threading.Lock()),
                     name="operator", daemon=True).start()
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        plant.stop()
    return 0
