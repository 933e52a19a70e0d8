"""A robot program in a process of its own, driving the simulated robot through its port
(``robot_port``) and taking parts from the part server: what an integrator's program
does, written against the two line protocols only (docs/part-server.md)::

    feeder run scenarios/lenses.yaml --part-server 7600 --no-sim-robot \\
        --sim-robot-port 7601 --duration 120
    python -m feeder_bt.plant.outside_robot --parts 127.0.0.1:7600 --robot 127.0.0.1:7601

Ask for a part, pick it, report it picked, place it, report it placed; a failed pick is
reported missed. Blocking calls: a program of its own may wait.
"""

from __future__ import annotations

import argparse
import sys
import threading

from feeder_bt.plant.client import PartClient, PartServerError, TcpLink


def _hostport(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host or "127.0.0.1", int(port)


class MotionLink:
    """The simulated robot's port: one motion line, one reply (when the motion ends)."""

    def __init__(self, host: str, port: int) -> None:
        self.link = TcpLink(host, port)

    def do(self, line: str, timeout: float = 120.0) -> str:
        self.link.send(line)
        reply = self.link.receive(timeout=timeout)
        if reply is None:
            raise PartServerError(f"the robot did not answer {line.split()[0]}")
        return reply

    def close(self) -> None:
        self.link.close()


def run(parts: PartClient, robot: MotionLink, count: int | None = None,
        stop: threading.Event | None = None) -> dict[str, int]:
    """The pick-and-place loop; returns what it did."""
    done = {"placed": 0, "missed": 0}
    robot.do("SAFE")
    while (count is None or done["placed"] < count) and not (stop and stop.is_set()):
        offer = parts.part(wait=2.0)
        if offer is None:
            continue
        got = robot.do(f"PICK {offer.id} {offer.x:.3f} {offer.y:.3f} {offer.rz:.3f} "
                       f"{offer.latch}")
        if not got.startswith("OK"):
            parts.missed(offer.id, got.split()[3].rstrip(":") if len(got.split()) > 3
                         else "missed_grab")
            done["missed"] += 1
            if "servo" in got:
                robot.do("RECOVER")
            continue
        parts.picked(offer.id)
        got = robot.do(f"PLACE {offer.type} {offer.rz:.3f}")
        if got.startswith("OK"):
            parts.placed(offer.id)
            done["placed"] += 1
        else:
            parts.missed(offer.id, "dropped")
            done["missed"] += 1
    return done


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m feeder_bt.plant.outside_robot",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="127.0.0.1:7600", metavar="HOST:PORT")
    ap.add_argument("--robot", default="127.0.0.1:7601", metavar="HOST:PORT")
    ap.add_argument("--hello", metavar="NAME:SECRET",
                    help="the robot's name and secret when the part server has a robots file")
    ap.add_argument("--count", type=int, help="stop after this many parts placed")
    args = ap.parse_args(argv)
    try:
        parts = PartClient.connect(*_hostport(args.parts))
        if args.hello:
            name, _, secret = args.hello.partition(":")
            parts.hello(name, secret)
        robot = MotionLink(*_hostport(args.robot))
        try:
            done = run(parts, robot, args.count)
        except KeyboardInterrupt:
            done = {}
        print(f"outside robot: {done}")
    except (PartServerError, ValueError, OSError) as e:
        print(f"outside robot: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
