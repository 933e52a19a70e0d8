"""Robots must be trusted. A robot proves who it is (challenge and response keyed by the
secret in the robots file, never the secret itself; or its address); at most N parts are outstanding per robot; a robot that takes parts
and never reports them is cut off with a fault for the operator; on the simulated cell a
PLACED the world did not see is a mismatch, counted and shown; ``--fast`` with
``--no-sim-robot`` is refused with the reason."""

from __future__ import annotations

import json
import threading

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.errors import FeederError
from feeder_bt.core.part_protocol import parse_offer, prove, secret_key
from feeder_bt.plant.adapters import _world_check
from feeder_bt.plant.client import LoopLink, PartClient, PartServerError, TcpLink
from feeder_bt.plant.options import PlantOptions
from feeder_bt.plant.part_server import PartServer
from feeder_bt.plant.robots import RobotsError, RobotTrust
from feeder_bt.plant.robots import main as robots_main
from tests.plant.test_part_server import Serving, Talk, _serving_with_parts

LENSES = "scenarios/lenses.yaml"


def _robots_file(tmp_path, capsys) -> tuple[str, str, str]:
    path = tmp_path / "robots.json"
    assert robots_main(["add", "cobra1", "--robots", str(path)]) == 0
    secret = capsys.readouterr().out.strip().rsplit(" ", 1)[1]
    assert robots_main(["allow", "cell2", "--robots", str(path), "--address",
                        "127.0.0.5"]) == 0
    assert robots_main(["add", "ur5", "--robots", str(path), "--plain-secret"]) == 0
    plain = capsys.readouterr().out.strip().rsplit(" ", 1)[1]
    assert (path.stat().st_mode & 0o077) == 0
    text = path.read_text()
    assert secret not in text and plain not in text        # only their hashes are kept
    assert json.loads(text)["robots"]["ur5"]["plain_secret"] is True
    assert "plain_secret" not in json.loads(text)["robots"]["cobra1"]   # off by default
    return str(path), secret, plain


class Line:
    """A robot's connection by hand: each line sent is kept, as a listener would see it."""

    def __init__(self, host: str, port: int, source: str = "127.0.0.1") -> None:
        import socket
        self.sock = socket.create_connection((host, port), timeout=20,
                                             source_address=(source, 0))
        self.f = self.sock.makefile("rwb")
        self.sent: list[str] = []

    def ask(self, line: str) -> str:
        self.sent.append(line)
        self.f.write(line.encode() + b"\n")
        self.f.flush()
        return self.f.readline().decode().rstrip("\n")

    def close(self) -> None:
        self.f.close()
        self.sock.close()


def test_robots_prove_who_they_are(tmp_path, capsys):
    path, secret, plain = _robots_file(tmp_path, capsys)
    s = _serving_with_parts(2)
    server = PartServer(s.desk, "127.0.0.1", 0, RobotTrust.load(path))
    host, port = server.start().split(":")
    done = threading.Event()
    thread = threading.Thread(target=lambda: Ticker(s.cell, fast=False).run(
        until=s.clock.now() + 60.0, stop=done.is_set, every=s.desk.serve_idle))
    thread.start()
    try:
        with PartClient.connect(host, int(port)) as stranger:
            assert stranger.help().startswith("PART")          # HELP is free
            with pytest.raises(PartServerError, match="HELLO NAME first"):
                stranger.part()
            with pytest.raises(PartServerError, match="wrong secret"):
                stranger.request("HELLO cobra1 not-the-secret")
            with pytest.raises(PartServerError, match="wrong proof"):
                stranger.hello("cobra1", "not-the-secret")      # a wrong response
            with pytest.raises(PartServerError, match="HELLO NAME first"):
                stranger.status()
        # the right response is accepted: the reference client answers the challenge
        robot = PartClient(TcpLink(host, int(port)))
        robot.hello("cobra1", secret)
        offer = robot.part(wait=10.0)
        assert offer is not None
        robot.release(offer.id)
        robot.close()
        # cell2 is known by its address alone: from 127.0.0.5 it needs no secret
        cell2 = Line(host, int(port), "127.0.0.5")
        assert cell2.ask("STATUS").startswith("OK STATUS state=RUNNING")
        cell2.close()
    finally:
        done.set()
        thread.join()
        server.close()
        s.close()
    assert server.server.refused_hellos == 2


def test_a_captured_hello_replayed_on_another_connection_is_refused(tmp_path, capsys):
    """What crosses the network for one connection is worth nothing on another: the exact
    lines of a successful HELLO, sent again from another address, get a new challenge and
    a refusal; the old plain ``HELLO NAME SECRET`` is refused unless the robots file opts
    that robot in; a PROOF without a challenge, or a second try at one, is refused."""
    path, secret, plain = _robots_file(tmp_path, capsys)
    s = _serving_with_parts(2)
    server = PartServer(s.desk, "127.0.0.1", 0, RobotTrust.load(path))
    host, port = server.start().split(":")
    done = threading.Event()
    thread = threading.Thread(target=lambda: Ticker(s.cell, fast=False).run(
        until=s.clock.now() + 60.0, stop=done.is_set, every=s.desk.serve_idle))
    thread.start()
    try:
        real = Line(host, int(port), "127.0.0.21")
        challenge = real.ask("HELLO cobra1")
        assert challenge.startswith("OK CHALLENGE ") and len(challenge.split()[2]) == 32
        nonce = challenge.split()[2]
        assert real.ask(f"PROOF {prove(secret_key(secret), nonce)}") == "OK HELLO cobra1"
        assert real.ask("STATUS").startswith("OK STATUS")
        captured = list(real.sent[:2])
        thief = Line(host, int(port), "127.0.0.66")
        again = thief.ask(captured[0])
        assert again.startswith("OK CHALLENGE ") and again != challenge   # a fresh nonce
        assert thief.ask(captured[1]).startswith("ERR HELLO: unknown robot, wrong proof")
        assert thief.ask("PART").startswith("ERR who are you?")
        # one try per challenge: the right answer to a used challenge is refused too
        assert thief.ask(f"PROOF {prove(secret_key(secret), again.split()[2])}") \
            .startswith("ERR PROOF: no challenge")
        # the old plain form, as the finding captured it: refused without the opt-in
        assert thief.ask(f"HELLO cobra1 {secret}").startswith("ERR HELLO:")
        assert thief.ask("PART").startswith("ERR who are you?")
        thief.close()
        real.close()
        # ... and accepted for a robot the file opts in (ur5: a language without HMAC)
        ur5 = Line(host, int(port))
        assert ur5.ask(f"HELLO ur5 {plain}") == "OK HELLO ur5"
        ur5.close()
        # the challenge is keyed by the hash the file keeps: a client given only the
        # secret computes the same key
        key = bytes.fromhex(json.loads(open(path).read())["robots"]["cobra1"]
                            ["secret_sha256"])
        assert key == secret_key(secret)
    finally:
        done.set()
        thread.join()
        server.close()
        s.close()
    assert server.server.refused_hellos == 3


def test_a_bad_robots_file_is_one_line(tmp_path):
    bad = tmp_path / "robots.json"
    bad.write_text(json.dumps({"format": "feeder_bt robots 1", "robots": {
        "cobra1": {"addresses": ["10.0.0.300"]}}}))
    with pytest.raises(RobotsError, match=r"robots\.cobra1\.addresses: '10\.0\.0\.300'"):
        RobotTrust.load(bad)
    bad.write_text(json.dumps({"format": "feeder_bt robots 1", "max_outstanding": 0,
                               "robots": {}}))
    with pytest.raises(RobotsError, match="max_outstanding: a whole number 1-100"):
        RobotTrust.load(bad)


def test_a_hoarder_is_cut_off_and_the_honest_robot_gets_the_parts():
    s = Serving(seed=1)
    s.program.kill()
    s.program = s.new_program("honest#1@10.0.0.8:1")
    hoarder = PartClient(LoopLink(s.desk, s.clock, "hoarder#1@10.0.0.9:1"))
    got: list[tuple[str, list[str]]] = []
    asking = [False]

    def every() -> None:
        s.program.step()
        reply = hoarder.poll()
        if reply is not None:
            got.append(reply)
            asking[0] = False
        if not asking[0]:                  # asks again at once, never reports anything
            hoarder.submit("PART")
            asking[0] = True
        s.desk.serve_idle()

    s.start()
    s.ticker.run(until=150.0, every=every)
    offers = [f for k, f in got if k == "PART"]
    refusals = [f[0] for k, f in got if k == "ERR"]
    # never more than N at once; as its records expire it may take a few more, until the
    # N-th unreported one cuts it off: at most 2 N - 1 in all
    n = s.desk.max_outstanding
    assert n <= len(offers) <= 2 * n - 1
    assert any("holds 4 parts not yet reported" in r for r in refusals)
    assert any("is cut off" in r for r in refusals)
    assert s.desk.counts["cut_off"] == 1 and s.cell.stats.faults["robot_cut_off"] == 1
    cut = [e for e in s.cell.stats.events if e.kind == "fault"
           and e.data.get("kind") == "robot_cut_off"]
    assert cut and cut[0].data["robot"] == "hoarder"
    honest = s.program.counts["placed"]
    assert honest > 40 and honest / (honest + len(offers)) >= 0.8, (honest, len(offers))
    assert s.world.lost() == 0
    s.close()


def test_a_placed_the_world_did_not_see_is_a_mismatch():
    s = _serving_with_parts(2)
    s.desk.verify_placed = _world_check(s.world)
    liar = Talk(s, "liar#1@10.0.0.7:1")
    offer = parse_offer(liar.say("PART")[1])
    assert liar.say(f"PICKED {offer.id}")[0] == "PICKED"
    kind, fields = liar.say(f"PLACED {offer.id}")
    assert kind == "ERR" and "counted as a mismatch" in fields[0]
    assert s.desk.counts["mismatch"] == 1 and s.desk.counts["placed"] == 0
    assert s.desk.counts["handed_out"] == sum(s.desk.counts[k] for k in (
        "placed", "missed", "released", "expired", "held_expired", "mismatch")) \
        + len(s.desk.handed)                       # the ledger balances
    assert s.cell.stats.total_retrieved == 0
    assert s.cell.stats.faults["placed_mismatch"] == 1
    s.close()


def test_the_report_shows_mismatches_and_the_honest_sim_robot_has_none(capsys):
    from feeder_bt.analysis.summary import summary
    r = run_job(RunOptions(scenario=LENSES, duration=60.0, fast=True, seed=2, view="none",
                           db=None, plant=PlantOptions(part_server="127.0.0.1:0")))
    ps = r["part_server"]
    assert ps["mismatch"] == 0 and ps["cut_off"] == 0 and ps["placed"] > 20
    assert ps["unaccounted"] == 0                  # the ledger balances
    assert "part server:" not in summary(r)
    r["part_server"] = {**ps, "mismatch": 3}
    assert "3 PLACED the world did not see (not counted)" in summary(r)


def test_fast_without_the_sim_robot_is_refused_with_the_reason():
    with pytest.raises(FeederError, match="--fast with --no-sim-robot: virtual time would "
                                          "race ahead of an outside robot"):
        run_job(RunOptions(scenario=LENSES, duration=10.0, fast=True, view="none", db=None,
                           plant=PlantOptions(part_server="127.0.0.1:0", sim_robot=False)))


def test_an_outside_program_drives_the_simulated_robot():
    from feeder_bt.plant.outside_robot import MotionLink, run
    from feeder_bt.plant.robot_port import RobotPort

    s = _serving_with_parts(2)
    s.desk.verify_placed = _world_check(s.world)
    server = PartServer(s.desk, "127.0.0.1", 0)
    port = RobotPort(s.hal.robot, s.scenario, "127.0.0.1", 0)
    parts_at, robot_at = server.start(), port.start()
    done = threading.Event()

    def every() -> None:
        port.pump()
        s.desk.serve_idle()

    thread = threading.Thread(target=lambda: Ticker(s.cell, fast=False).run(
        until=s.clock.now() + 300.0, stop=done.is_set, every=every))
    thread.start()
    try:
        host, p = parts_at.split(":")
        with PartClient.connect(host, int(p)) as parts:
            robot = MotionLink(*robot_at.split(":")[:1], int(robot_at.split(":")[1]))
            assert robot.do("SPEED 1e-300").startswith("ERR SPEED")
            assert robot.do("HELD") == "OK HELD -"
            did = run(parts, robot, count=3)
            robot.close()
    finally:
        done.set()
        thread.join()
        port.close()
        server.close()
    assert did["placed"] == 3
    # every PLACED was seen by the world: believed, none a mismatch
    assert s.desk.counts["placed"] == 3 and s.desk.counts["mismatch"] == 0
    assert s.world.placed_by_type["lens"] == 3 == s.cell.stats.total_retrieved
    s.close()


def test_the_robot_port_is_for_this_machine_and_needs_no_sim_robot():
    from feeder_bt.plant.robot_port import RobotPort
    with pytest.raises(FeederError, match="for this machine only"):
        RobotPort(None, None, "0.0.0.0", 7601)
    with pytest.raises(FeederError, match="--sim-robot-port: with --no-sim-robot"):
        run_job(RunOptions(scenario=LENSES, duration=5.0, view="none", db=None,
                           plant=PlantOptions(part_server="127.0.0.1:0",
                                              sim_robot_port="127.0.0.1:0")))
