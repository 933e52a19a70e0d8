"""The part server: robots pull parts from the cell over a line protocol.

Most tests run the simulated robot program lock-step with virtual time (``LoopLink``), so
they are deterministic; one test talks over real TCP on loopback and asserts only what was
said, never how long it took."""

from __future__ import annotations

import math
import threading

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.behaviours.desk import Desk
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import SimClock
from feeder_bt.core.part_protocol import (
    Offer,
    ProtocolError,
    parse_offer,
    parse_reply,
    parse_request,
)
from feeder_bt.hal.interfaces import PickTarget
from feeder_bt.plant.client import LoopLink, PartClient, PartServerError
from feeder_bt.plant.options import PlantOptions
from feeder_bt.plant.part_server import PartServer, install
from feeder_bt.plant.sim_robot import SimRobotProgram
from feeder_bt.sim.devices import make_sim_hal

LENSES = "scenarios/lenses.yaml"


# --------------------------------------------------------------------------- protocol

def test_requests_parse_and_bad_ones_say_why():
    r = parse_request("part lens WITHIN 1.5 wait 5")
    assert (r.command, r.part_type, r.within_s, r.wait_s) == ("PART", "lens", 1.5, 5.0)
    assert parse_request("PART").part_type is None
    assert parse_request("PLACED 17").part_id == 17
    assert parse_request("MISSED 3 nothing under the gripper").why.startswith("nothing")
    assert parse_request("PREPARE 4 lens").count == 4
    for bad, why in [("", "empty"), ("FETCH", "unknown command"), ("PICKED", "needs a part id"),
                     ("PICKED x", "whole number"), ("PART lens WAIT", "WITHIN s or WAIT s"),
                     ("PART WAIT -1", "0 or more"), ("STATUS now", "no arguments"),
                     ("PART " + "x" * 300, "longer than"), ("PART l\u00e9ns", "ASCII")]:
        with pytest.raises(ProtocolError, match=why):
            parse_request(bad)


def test_an_offer_survives_its_line():
    offer = Offer(12, "lens", 812.25, 233.5, 0.0, -12.0, 8_000_123, 2.5)
    kind, fields = parse_reply(offer.line())
    assert kind == "PART" and parse_offer(fields) == offer
    assert parse_reply("ERR PICKED 3: no") == ("ERR", ["PICKED 3: no"])


# --------------------------------------------------------------------------- lock-step runs

class Serving:
    """A simulated cell fed through the part server by the simulated robot's program."""

    def __init__(self, seed: int = 1, grace_s: float = 5.0, skip_idle: bool = True) -> None:
        scenario, spec = load_scenario(LENSES)
        self.clock = SimClock()
        self.hal = make_sim_hal(scenario, spec, self.clock, seed)
        self.world = self.hal.world
        self.cell = Cell(spec, self.hal, self.clock)
        self.cell.load(scenario)
        self.desk = Desk(self.clock, pick_grace_s=grace_s)
        install(self.cell, self.desk)
        self.scenario = scenario
        self.program = self.new_program("sim-robot")
        self.ticker = Ticker(self.cell, fast=True, skip_idle=skip_idle)
        self.retrieved: list[int] = []      # the cell's retrieved events, by part id
        self.gripped: list[tuple[int, int]] = []     # (commanded id, world id) per grip
        self.released: list[int] = []       # world ids released at a place pose
        self._watch()

    def new_program(self, name: str) -> SimRobotProgram:
        return SimRobotProgram(PartClient(LoopLink(self.desk, self.clock, name)),
                               self.hal.robot, self.scenario, self.clock)

    def _watch(self) -> None:
        grip, release = self.world.grip, self.world.release

        def gripping(target, t):
            res = grip(target, t)
            self.gripped.append((target.part_id, res.part_id))
            return res

        def releasing(pose, t):
            pid = release(pose, t)
            self.released.append(pid)
            return pid

        self.world.grip, self.world.release = gripping, releasing

    def start(self) -> None:
        self.cell.start()                   # a first start makes the run's statistics
        self.cell.stats.listeners.append(
            lambda ev: self.retrieved.append(ev.data["id"]) if ev.kind == "retrieved" else None)

    def every(self) -> None:
        self.program.step()
        self.desk.serve_idle()

    def run(self, until: float, stop=None) -> None:
        self.ticker.run(until=until, stop=stop, every=self.every)

    def close(self) -> None:
        self.hal.close()


def test_parts_placed_through_the_client_are_accounted_part_by_part():
    s = Serving(seed=3)
    s.start()
    s.run(150.0)
    s.cell.stop()
    s.run(s.clock.now() + 10.0, stop=lambda: s.cell.state is CellState.STOPPED)
    assert s.cell.state is CellState.STOPPED
    s.run(s.clock.now() + 3.0)      # the robot finishes its cycle; the stopped cell listens
    assert s.program.doing is None and s.program.offer is None
    stats, desk, world = s.cell.stats, s.desk, s.world
    assert stats.total_retrieved > 60
    # the cell counted exactly the parts the robot reported placed, each once, and the
    # robot placed exactly the parts it gripped, at their place pose
    assert s.retrieved == [cmd for cmd, _ in s.gripped]
    assert len(set(s.retrieved)) == len(s.retrieved)
    assert s.released == [wid for _, wid in s.gripped]
    assert world.placed_by_type["lens"] == stats.retrieved["lens"] == desk.counts["placed"]
    assert world.misplaced_by_type == {} and world.lost() == 0 and world.duplicated() == 0
    # every part handed out is accounted for on the desk
    c = desk.counts
    assert c["handed_out"] == (c["placed"] + c["missed"] + c["released"] + c["expired"]
                               + c["held_expired"] + len(desk.handed))
    assert s.program.counts["refused"] == 0 and c["refused"] == 0
    s.close()


def test_same_seed_same_figures_with_and_without_skipping_ticks():
    def figures(skip: bool) -> tuple:
        s = Serving(seed=5, skip_idle=skip)
        s.start()
        s.run(60.0)
        # the world as of the clock's time: skipping idle ticks, its last step may be earlier
        s.world.step(s.clock.now())
        out = (dict(s.cell.stats.retrieved), s.cell.stats.counts["located"],
               dict(s.desk.counts), s.world.census())
        s.close()
        return out

    assert figures(True) == figures(False)


def _until_picking(s: Serving) -> Offer:
    s.run(120.0, stop=lambda: s.clock.now() > 30.0 and s.program.doing == "pick"
          and s.program.job is not None and not s.program.job.done)
    assert s.program.doing == "pick" and s.program.offer is not None
    return s.program.offer


def test_killing_the_robot_mid_pick_loses_no_part():
    s = Serving(seed=2, grace_s=2.0)
    s.start()
    offer = _until_picking(s)
    w = s.world
    # the test (not the cell) finds the part the robot was going for, by the truth
    target = PickTarget(offer.id, offer.x, offer.y, offer.rz, offer.latch)
    cx, cy = w.commanded_xy(target, w.t)
    part = min(w.on_horizontal.values(),
               key=lambda p: math.hypot(w.part_xy(p, w.t)[0] - cx, w.part_xy(p, w.t)[1] - cy))
    placed_before = s.cell.stats.total_retrieved
    expired: list[dict] = []
    s.cell.stats.listeners.append(
        lambda ev: expired.append(ev.data) if ev.kind == "part_expired" else None)
    s.program.kill()                                   # mid-pick: no word to the server
    assert offer.id in s.desk.handed
    s.run(s.clock.now() + offer.left_s + 2.0 + 1.0)
    assert offer.id not in s.desk.handed               # timed out ...
    assert s.desk.counts["expired"] == 1                # ... counted ...
    assert [e["id"] for e in expired] == [offer.id] and not expired[0]["picked"]
    assert s.cell.stats.counts["unreported"] == 1
    s.run(s.clock.now() + 20.0)
    assert part.where in ("return", "hopper", "incline", "horizontal")   # ... recirculated
    assert w.lost() == 0 and w.duplicated() == 0 and w.gripper is None
    assert s.cell.stats.total_retrieved == placed_before
    # a robot that connects again feeds on
    s.program = s.new_program("sim-robot-2")
    s.run(s.clock.now() + 40.0)
    assert s.cell.stats.total_retrieved > placed_before
    assert w.lost() == 0
    s.close()


def test_killing_the_robot_while_it_places_counts_the_unreported_part():
    s = Serving(seed=2)
    s.start()
    s.run(120.0, stop=lambda: s.clock.now() > 30.0 and s.program.doing == "place")
    offer = s.program.offer
    assert offer is not None
    s.run(s.clock.now() + 0.05)           # PICKED reaches the desk on the next tick
    assert s.desk.handed[offer.id].picked
    s.program.kill()          # the simulated robot lets a cut-short place go at its pose
    s.run(s.clock.now() + 31.0)
    assert s.desk.counts["held_expired"] == 1 and s.desk.counts["expired"] == 0
    # the world has the part placed; the cell, never told, did not count it retrieved
    assert s.world.placed_by_type["lens"] == s.cell.stats.retrieved["lens"] + 1
    assert s.world.gripper is None and s.world.lost() == 0
    s.close()


def test_the_part_server_feeds_at_least_90_percent_of_the_retrieve_tree():
    opts = {"scenario": LENSES, "duration": 300.0, "fast": True, "seed": 1, "view": "none",
            "db": None}
    built_in = run_job(RunOptions(**opts))
    served = run_job(RunOptions(**opts, plant=PlantOptions(part_server="127.0.0.1:0")))
    assert served["parts"]["lost"] == 0 and served["parts"]["duplicated"] == 0
    assert served["parts_per_minute"] >= 0.9 * built_in["parts_per_minute"]
    ps = served["part_server"]
    assert ps["placed"] == served["parts"]["retrieved"]["lens"]
    # the world placed what the cell counted, plus at most a part the stop found between
    # its release and the robot's report
    in_hand = ps["picked"] - ps["placed"]
    assert served["world"]["placed"]["lens"] == ps["placed"] + in_hand
    assert in_hand <= ps["outstanding"] <= 1
    assert ps["handed_out"] == ps["placed"] + ps["missed"] + ps["released"] + \
        ps["expired"] + ps["held_expired"] + ps["outstanding"]


# --------------------------------------------------------------------------- over TCP

def test_a_robot_over_tcp_gets_parts_and_is_refused_what_is_not_its_own():
    s = Serving(seed=1)
    s.program.kill()                        # no simulated robot here: the test is the robot
    s.start()
    s.run(80.0, stop=lambda: s.cell.ctx is not None and len(s.cell.ctx.queue) >= 4)
    assert len(s.cell.ctx.queue) >= 4
    server = PartServer(s.desk, "127.0.0.1", 0)
    host, port = server.start().split(":")
    done = threading.Event()
    real_time = Ticker(s.cell, fast=False)  # paced to the wall clock while we talk
    thread = threading.Thread(target=lambda: real_time.run(
        until=s.clock.now() + 30.0, stop=done.is_set, every=s.desk.serve_idle))
    thread.start()
    try:
        with PartClient.connect(host, int(port)) as robot, \
                PartClient.connect(host, int(port)) as other:
            assert robot.help().split() == ["PART", "PICKED", "PLACED", "MISSED", "RELEASE",
                                            "PREPARE", "STATUS", "HELP", "QUIT"]
            assert "WITHIN" in robot.help("part")
            status = robot.status()
            assert status["state"] == "RUNNING" and status["scenario"] == "lenses"
            assert int(status["encoder_bits"]) == 24 and float(status["counts_per_mm"]) > 0
            assert robot.prepare(2, "lens") >= 1
            offer = robot.part("lens")
            assert offer is not None and offer.type == "lens" and offer.left_s > 0
            with pytest.raises(PartServerError, match="handed to another robot"):
                other.picked(offer.id)
            with pytest.raises(PartServerError, match="unknown part type"):
                other.part("washer")
            with pytest.raises(PartServerError, match="unknown command"):
                other.request("FETCH 1")
            assert robot.release(offer.id) is True          # back into the queue
            with pytest.raises(PartServerError, match="not handed to a robot"):
                robot.missed(offer.id)
            again = robot.part()
            assert again is not None
            robot.missed(again.id, "nothing under the gripper")
            taken = other.part()
            kept = other.part()
            assert taken is not None and kept is not None
            with pytest.raises(PartServerError, match="handed to another robot"):
                robot.missed(kept.id)             # ``other`` is still connected
        # ``other`` went away holding two offers; it reconnects and reports one of them
        for _ in range(1000):                    # the server notices the hang-ups
            if not server.server.robots:
                break
            threading.Event().wait(0.01)
        with PartClient.connect(host, int(port)) as back:
            back.missed(kept.id, "lost it when the program stopped")
        assert s.desk.counts["missed"] == 2 and s.desk.counts["released"] == 1
    finally:
        done.set()
        thread.join()
        server.close()
    s.ticker = Ticker(s.cell, fast=True)                   # virtual time again
    s.run(s.clock.now() + taken.left_s + 10.0)
    assert taken.id not in s.desk.handed and s.desk.counts["expired"] == 1
    assert s.world.lost() == 0
    s.close()


def test_requests_while_stopped_are_answered():
    s = Serving(seed=1)
    s.program.kill()
    client = PartClient(LoopLink(s.desk, s.clock, "robot"))
    client.submit("PART")
    client.submit("STATUS")
    s.run(0.1)
    assert client.poll() == ("NONE", ["STOPPED"])
    kind, fields = client.poll()
    assert kind == "STATUS" and "state=STOPPED" in fields
    # every term of the ledger (docs/part-server.md) is in STATUS
    assert {f.split("=")[0] for f in fields} >= {"placed", "missed", "released", "expired", "held_expired"}
    s.close()


def test_a_bad_part_server_address_is_one_line(capsys):
    from feeder_bt.cli.main import main
    code = main(["run", LENSES, "--fast", "--duration", "1", "--view", "none", "--no-db",
                 "--part-server", "127.0.0.1:99999"])
    err = capsys.readouterr().err
    assert code != 0 and "--part-server" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------- the desk's rules

class Talk:
    """One robot talking to a serving cell's desk through the loop link, tick by tick."""

    def __init__(self, s: Serving, name: str = "robot") -> None:
        self.s = s
        self.client = PartClient(LoopLink(s.desk, s.clock, name))

    def say(self, line: str) -> tuple[str, list[str]]:
        self.client.submit(line)
        t_end = self.s.clock.now() + 10.0
        while True:
            got = self.client.poll()
            if got is not None:
                return got
            assert self.s.clock.now() < t_end, f"no answer to {line}"
            self.s.run(self.s.clock.now() + 0.01)


def _serving_with_parts(n: int = 2) -> Serving:
    s = Serving(seed=1)
    s.program.kill()
    s.start()
    s.run(60.0, stop=lambda: s.cell.ctx is not None and len(s.cell.ctx.queue) >= n)
    assert len(s.cell.ctx.queue) >= n
    return s


def test_a_report_after_the_time_out_counts_the_part_where_the_robot_says():
    s = _serving_with_parts()
    robot = Talk(s)
    kind, fields = robot.say("PART")
    offer = parse_offer(fields)
    s.run(s.clock.now() + offer.left_s + 6.0)
    assert s.desk.counts["expired"] == 1
    assert robot.say(f"PLACED {offer.id}")[0] == "PLACED"          # late, but believed
    assert (s.desk.counts["expired"], s.desk.counts["late_reports"],
            s.desk.counts["placed"]) == (0, 1, 1)
    assert robot.say(f"PLACED {offer.id}")[0] == "ERR"             # once only
    s.close()


def test_a_picked_part_cannot_be_released_and_reports_name_their_robot():
    s = _serving_with_parts()
    robot, other = Talk(s, "robot"), Talk(s, "other")
    offer = parse_offer(robot.say("PART lens")[1])
    assert robot.say(f"PICKED {offer.id}") == ("PICKED", [str(offer.id)])
    kind, fields = robot.say(f"RELEASE {offer.id}")
    assert kind == "ERR" and "place it" in fields[0]
    kind, fields = other.say(f"MISSED {offer.id}")
    assert kind == "ERR" and "another robot" in fields[0]
    assert robot.say(f"MISSED {offer.id} nothing under the cup")[0] == "MISSED"
    assert s.cell.stats.counts["missed"] == 1
    s.close()


def test_within_hands_out_only_parts_in_reach_by_then():
    s = _serving_with_parts(1)
    robot = Talk(s)
    ctx, sp = s.cell.ctx, s.cell.cell.robot
    # the first parts are still upstream of the reach: none is reachable at once ...
    kind, fields = robot.say("PART WITHIN 0")
    if kind == "PART":
        offer = parse_offer(fields)
        moved = (s.hal.robot_position.belt_encoder() - offer.latch) \
            / s.cell.cell.encoder.counts_per_mm
        assert math.hypot(offer.x + moved - sp.base_mm[0], offer.y - sp.base_mm[1]) \
            <= sp.reach_mm + 1.0
    else:
        assert (kind, fields) == ("NONE", ["empty"])
        # ... but waiting for one hands it out as it comes within reach
        kind, fields = robot.say("PART WITHIN 0 WAIT 30")
        assert kind == "PART"
        offer = parse_offer(fields)
        moved = (s.hal.robot_position.belt_encoder() - offer.latch) \
            / s.cell.cell.encoder.counts_per_mm
        assert math.hypot(offer.x + moved - sp.base_mm[0], offer.y - sp.base_mm[1]) \
            <= sp.reach_mm + 1.0
    assert ctx is s.cell.ctx
    s.close()


def test_quit_and_over_long_lines_close_the_connection(capsys):
    import socket

    s = Serving(seed=1)
    s.program.kill()
    server = PartServer(s.desk, "127.0.0.1", 0)
    host, port = server.start().split(":")
    done = threading.Event()
    thread = threading.Thread(target=lambda: Ticker(s.cell, fast=False).run(
        until=s.clock.now() + 30.0, stop=done.is_set, every=s.desk.serve_idle))
    thread.start()
    try:
        with socket.create_connection((host, int(port)), timeout=10) as sock:
            f = sock.makefile("rwb")
            f.write(b"quit\r\n")
            f.flush()
            assert f.readline() == b"OK BYE\n" and f.readline() == b""
        with socket.create_connection((host, int(port)), timeout=10) as sock:
            f = sock.makefile("rwb")
            f.write(b"PART " + b"x" * 400 + b"\n")
            f.flush()
            assert f.readline().startswith(b"ERR line longer than") and f.readline() == b""
        # the reference client by hand: one reply per request, refusals as they come
        from feeder_bt.plant.client import main
        assert main([f"{host}:{port}", "help", "PICKED 12345", "STATUS", "QUIT"]) == 0
        out = capsys.readouterr().out.splitlines()
        assert out[0].startswith("OK HELP PART") and out[1].startswith("ERR PICKED 12345")
        assert out[2].startswith("OK STATUS state=STOPPED") and out[3] == "OK BYE"
        assert main([f"{host}:1"]) == 1 and "cannot connect" in capsys.readouterr().err
    finally:
        done.set()
        thread.join()
        server.close()
        s.close()


def test_robot_faults_under_the_part_server_lose_nothing(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text("scripted:\n"
                    "  - {at_s: 30, kind: servo_timeout}\n"
                    "  - {at_s: 40, kind: missed_grab}\n"
                    "  - {at_s: 50, kind: comms_lost, device: adept, outage_s: 2.0}\n"
                    "  - {at_s: 70.3, kind: comms_lost, device: adept, outage_s: 3.0}\n")
    r = run_job(RunOptions(scenario=LENSES, duration=120.0, fast=True, seed=3, view="none",
                           db=None, faults=str(plan),
                           plant=PlantOptions(part_server="127.0.0.1:0")))
    ps, parts = r["part_server"], r["parts"]
    assert r["injected"].get("servo_timeout") == 1 and r["injected"].get("missed_grab") == 1
    assert parts["lost"] == 0 and parts["duplicated"] == 0 and parts["misplaced"] == {}
    # the injected missed grab, and perhaps a grip of the simulator's own that did not hold
    assert r["faults"]["servo_timeout"] == 1 and r["misses"]["missed_grab"] >= 1
    assert r["recoveries"].get("servo_timeout", 0) == 0     # the robot's own business now
    # the world placed what the cell counted, plus at most the part still being placed
    in_hand = ps["picked"] - ps["placed"]
    assert r["world"]["placed"]["lens"] == parts["retrieved"]["lens"] + in_hand
    assert in_hand <= ps["outstanding"] <= 1
    assert ps["handed_out"] == ps["placed"] + ps["missed"] + ps["released"] + ps["expired"] + \
        ps["held_expired"] + ps["outstanding"]
    assert ps["refused"] == 0 and ps["sim_robot"]["refused"] == 0


def test_a_part_server_port_in_use_is_one_line(capsys):
    import socket

    from feeder_bt.cli.main import main
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(["run", LENSES, "--fast", "--duration", "1", "--view", "none", "--no-db",
                     "--part-server", f"127.0.0.1:{port}"])
    err = capsys.readouterr().err
    assert code != 0 and f"--part-server 127.0.0.1:{port}" in err and "Traceback" not in err


def test_the_operator_hears_when_no_robot_asks_for_parts():
    s = _serving_with_parts()                      # the robot program was killed
    s.run(s.clock.now() + 31.0)
    told = [e for e in s.cell.stats.events if e.kind == "fault"
            and e.data.get("kind") == "robot_idle"]
    assert len(told) == 1 and s.cell.stats.faults["robot_idle"] == 1
    robot = Talk(s)
    assert robot.say("STATUS")[0] == "STATUS"      # a robot is back
    s.run(s.clock.now() + 0.05)
    assert s.cell.stats.recoveries["robot_idle"] == 1
    assert [e.data.get("kind") for e in s.cell.stats.events
            if e.kind == "recovered"][-1:] == ["robot_idle"]
    s.close()
