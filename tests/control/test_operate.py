"""Operating a real simulated cell. The operator's
commands and their limits, the dashboard's snapshot, the report's feed time, and
`feeder run --ui`'s options (with docs/operator-ui.md's commands).

The cell runs in virtual time (``SimRig``)."""

from __future__ import annotations

import json
import re
import shlex
import socket

import pytest

from feeder_bt.cli.main import build_parser, main
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import CellState
from feeder_bt.control.operate import Limits, parse_speeds
from feeder_bt.control.users import UsersFile
from feeder_bt.ui import parse_bind
from tests.support.uiutil import LENSES, ROOT, SimRig

# ---------------------------------------------------------------- --ui options


def test_ui_bind_parsing():
    assert parse_bind("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert parse_bind(":9000") == ("127.0.0.1", 9000)
    assert parse_bind("[::1]:0") == ("::1", 0)
    args = build_parser().parse_args(["run", "x.yaml", "--ui"])
    assert (args.ui, args.start, args.duration) == ("127.0.0.1:8080", None, None)
    args = build_parser().parse_args(["run", "x.yaml", "--ui", "0.0.0.0:81", "--start"])
    assert (args.ui, args.start) == ("0.0.0.0:81", True)
    for bad in ("nope", "host:http", "h:70000"):
        with pytest.raises(SystemExit) as e:
            build_parser().parse_args(["run", "x.yaml", "--ui", bad])
        assert e.value.code == 2


def test_run_ui_refuses_bad_set_ups_in_one_line(tmp_path, capsys):
    empty = tmp_path / "none.json"
    assert main(["run", str(LENSES), "--ui", "127.0.0.1:0", "--users", str(empty),
                 "--no-db", "--view", "none"]) == 2
    assert "no users in" in capsys.readouterr().err
    users = UsersFile(tmp_path / "users.json")
    users.add("alice", "alice-secret-1")
    assert main(["run", str(LENSES), "--ui", "127.0.0.1:0", "--users", str(users.path),
                 "--fast", "--no-db"]) == 2
    assert "drop --fast" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["run", str(LENSES), "--ui", f"127.0.0.1:{port}", "--users",
                     str(users.path), "--no-db", "--view", "none", "--duration", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot listen" in err[0]


def test_operator_ui_doc_commands_are_real_commands():
    """docs/operator-ui.md's interactive examples (console blocks: they ask for a password
    or serve until Ctrl-C, so test_docs.py cannot run them) parse with the real parser;
    tests/ui/test_http.py and test_browser.py run the same `feeder run --ui`."""
    doc = (ROOT / "docs" / "operator-ui.md").read_text()
    lines = [line[2:] for block in re.findall(r"```console\n(.*?)```", doc, flags=re.S)
             for line in block.splitlines() if line.startswith("$ feeder ")]
    lines += [line.split("| ", 1)[1] for block in re.findall(r"```sh\n(.*?)```", doc, flags=re.S)
              for line in block.splitlines() if "| feeder " in line]
    assert len(lines) >= 6
    for line in lines:
        args = build_parser().parse_args(shlex.split(line)[1:])
        assert args.handler is not None


# -------------------------------------------------------------------- the cell


def test_limits_come_from_the_cell():
    _, spec = load_scenario(LENSES)
    lim = Limits.of(spec)
    assert lim.horizontal_max_mm_s == spec.conveyors["horizontal"].max_mm_s == 400
    cur = {"horizontal_mm_s": 150.0, "incline_pct": 40.0}
    assert parse_speeds({"horizontal_mm_s": "180"}, lim, cur) == {"horizontal_mm_s": 180.0}
    for args, needle in [
        ({"horizontal_mm_s": 401}, "above the horizontal conveyor's max_mm_s 400"),
        ({"horizontal_mm_s": 0}, "must be at least 1 mm/s"),
        ({"horizontal_mm_s": 1e-300}, "must be at least 1 mm/s"),
        ({"horizontal_mm_s": "fast"}, "must be a number"),
        ({"horizontal_mm_s": True}, "must be a number"),
        ({"horizontal_mm_s": float("nan")}, "finite"),
        ({"horizontal_mm_s": int("9" * 401)}, "finite"),        # not a 500
        ({"horizontal_mm_s": "9" * 401}, "at most 32 characters"),
        ({"horizontal_mm_s": "1e999"}, "finite"),
        ({"incline_pct": 201}, "1-200 %"),
        ({"incline_pct": -1}, "1-200 %"),
        ({"incline_pct": 1e-300}, "1-200 %"),
        ({"robot_speed_pct": 0}, "robot speed"),
        ({"robot_speed_pct": 1e-300}, "robot speed must be 1-200 %"),
        ({"robot_speed_pct": "\u0661\u0660\u0660"}, "ASCII digits"),   # Arabic 100
        ({"horizontal_mm_s": "\uff11\uff10\uff10"}, "ASCII digits"),   # full-width 100
        ({"robot_speed_pct": 250}, "robot speed"),
        ({"horizontal_mm_s": 300, "incline_pct": 150}, "450 mm/s is above the incline"),
        ({"belt": 3}, "unknown speed 'belt'"),
        ({}, "no speed given"),
    ]:
        with pytest.raises(Exception, match=needle):
            parse_speeds(args, lim, cur)
    with pytest.raises(Exception, match="auto-adjuster may drive"):
        parse_speeds({"incline_pct": 150}, lim, cur, adjuster_max_mm_s=300)


def test_operator_commands_on_the_simulated_cell():
    rig = SimRig()
    cell = rig.cell
    out = rig.do("speeds", horizontal_mm_s=180)
    assert not out.ok and out.status == 409 and "start it first" in out.message
    assert rig.do("resume").status == 409 and cell.state is CellState.STOPPED
    assert rig.do("start").ok and cell.state is CellState.STARTING
    rig.run_until(CellState.RUNNING)
    rig.run(1.0)
    before = rig.horizontal()
    assert before >= 150

    bad = rig.do("speeds", horizontal_mm_s=500)
    assert (bad.ok, bad.status) == (False, 400) and "max_mm_s 400" in bad.message
    rig.run(0.2)
    assert rig.horizontal() in (before, before + 5)  # only the adjuster's own step

    assert rig.do("adjust", engaged=False).ok and not cell.auto_adjust
    assert rig.do("speeds", horizontal_mm_s=173).ok
    rig.run(3.0)                                    # six adjust periods: held, not moved
    assert rig.horizontal() == 173.0
    assert rig.do("adjust", engaged=True).ok
    rig.run(1.1)
    assert rig.horizontal() != 173.0                # the adjuster is back in charge

    assert rig.do("load", scenario="squares").status == 409
    assert rig.do("pause").ok and cell.state is CellState.PAUSED
    rig.run(0.5)
    assert rig.horizontal() == 0.0
    assert rig.do("resume").ok
    assert rig.do("stop").ok
    rig.run_until(CellState.STOPPED)
    assert rig.do("stop").status == 409
    assert rig.do("load", scenario="nope").status == 400
    assert rig.do("load", scenario="squares").ok and cell.scenario.name == "squares"
    assert rig.do("start", now=True).status == 400
    assert rig.do("fly").status == 400

    actions = [a["action"] for a in rig.ops.report()["commands"]]
    assert actions == ["start", "adjust", "speeds", "adjust", "pause", "resume", "stop", "load"]
    assert {"t", "user", "action", "horizontal_mm_s"} <= set(rig.ops.report()["commands"][2])


def test_a_held_adjuster_is_kept_across_a_restart():
    rig = SimRig()
    assert rig.do("adjust", engaged=False).ok
    assert rig.do("start").ok
    rig.run_until(CellState.RUNNING)
    rig.run(3.0)
    assert rig.horizontal() == rig.scenario.present.horizontal_mm_s   # never adjusted


def test_dashboard_snapshot():
    rig = SimRig()
    status, history, messages = rig.panel.snapshot()
    assert status["state"] == "STOPPED" and status["tree"] == "" and status["tree_part"] is None
    assert "lenses" in status["scenarios"] and status["limits"]["horizontal_max_mm_s"] == 400
    json.dumps(status)                              # plain data only
    rig.do("start")
    samples = 0

    def every() -> None:
        nonlocal samples
        samples += 1
        rig.panel.snapshot()

    rig.ticker.run(until=60.0, every=every)
    status, history, messages = rig.panel.snapshot()
    assert status["state"] == "RUNNING" and status["tree_part"] == "feeding"
    assert "[*]" in status["tree"] and "retrieve" in status["tree"]
    assert status["total_fed"] > 0 and status["last_part"]["type"] == "lens"
    assert status["hal"]["horizontal_mm_s"] == rig.horizontal() > 0
    assert status["run_time_s"] == pytest.approx(60.0, abs=0.1)
    assert 55 <= len(history) <= 61                 # one sample per second of clock time
    assert all(b[0] > a[0] for a, b in zip(history, history[1:], strict=False))
    assert history[-1][1] > 0                       # parts/min over the last minute
    kinds = {m.kind for m in messages}
    assert "state" in kinds and "operator" in kinds
    assert not kinds & {"located", "retrieved", "speeds"}
    assert [m.seq for m in messages] == sorted(m.seq for m in messages)


def test_ui_report_feed_time_is_the_time_between_starts_and_stops():
    from feeder_bt.app.run import _FeedSpan

    rig = SimRig()
    span = _FeedSpan(rig.cell)
    assert span.seconds(rig.clock.now()) == 0.0             # never started
    rig.do("start")
    t0 = rig.clock.now()
    rig.run(10.0)
    rig.do("stop")
    t1 = rig.clock.now()
    rig.run_until(CellState.STOPPED)
    rig.run(5.0)                                            # idle: not feeding time
    assert span.seconds(rig.clock.now()) == pytest.approx(t1 - t0)
    stats = rig.cell.stats
    rig.do("start")
    t2 = rig.clock.now()
    rig.run(3.0)
    now = rig.clock.now()
    earlier = (t1 - t0) if rig.cell.stats is stats else 0.0  # the cell kept counting, or not
    assert span.seconds(now) == pytest.approx(earlier + now - t2)


def test_reloading_the_run_scenario_keeps_its_overlay(tmp_path):
    """``feeder run X --overlay O --ui``: the operator who loads X again (after a stop)
    gets X with O, as the run had it; another scenario comes without it."""
    overlay = tmp_path / "o.yaml"
    overlay.write_text("present: {horizontal_mm_s: 173}\n")
    rig = SimRig()
    rig.cell.scenario, _ = load_scenario(LENSES, overlay=overlay)
    assert rig.cell.scenario.present.horizontal_mm_s == 173
    out = rig.do("load", scenario="lenses")
    assert out.ok and out.message == "scenario lenses loaded with its overlay o.yaml"
    assert rig.cell.scenario.present.horizontal_mm_s == 173
    assert rig.ops.report()["commands"][-1]["overlay"] == "o.yaml"
    assert rig.do("load", scenario="squares").ok
    assert rig.cell.scenario.overlay_path is None
    assert rig.do("load", scenario="lenses").message == "scenario lenses loaded"
    assert rig.cell.scenario.present.horizontal_mm_s != 173
