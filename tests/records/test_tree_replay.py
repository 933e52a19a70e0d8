"""The trees' history in the event log, and `feeder replay`. A fast fault run
(virtual time, fixed seeds, a scripted e-stop) records, besides the log, what the trees
really were after every tick; the replay at any time, and one second before the fault,
must match it node for node. The log must stay compact."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from py_trees.common import Status

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.cli.replay_cmd import node_paths
from feeder_bt.records.eventlog import open_readonly
from feeder_bt.records.treelog import STATUS_NAMES, TreeTrace, read_trace

LENSES = str(Path("scenarios/lenses.yaml").resolve())
FAULT_AT = 40.0
PLAN = f"seed: 0\nscripted:\n  - {{at_s: {FAULT_AT}, kind: estop, release_after_s: 5}}\n"
MOVE_BYTES = 3.0             # bound: packed bytes per recorded status change
CHUNK_BYTES_PER_HOUR = 1e6   # bound: the trees' history (and blackboard) per hour of a run


def live_paths(root, part: str) -> dict[str, str]:
    """Each node's status by its place (child indexes), walked here, not by the recorder."""
    out: dict[str, str] = {}
    stack = [(root, part)]
    while stack:
        node, path = stack.pop()
        out[path] = node.status.value.lower()
        stack.extend((kid, f"{path}/{i}") for i, kid in enumerate(node.children))
    return out


@pytest.fixture(scope="module")
def fault_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("replay")
    plan = tmp / "estop.yaml"
    plan.write_text(PLAN)
    db = tmp / "feeder.db"
    truth: dict[float, dict[str, str]] = {}       # tick time -> statuses of the feeding tree
    traces: list[TreeTrace] = []
    orig = TreeTrace.after_tick

    def spy(self: TreeTrace) -> None:
        orig(self)
        if not traces:
            traces.append(self)
        cell = self.cell
        if cell.root is not None and cell.root is cell.feeding:
            truth[cell.clock.now()] = live_paths(cell.root, "feeding")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(TreeTrace, "after_tick", spy)
        report = run_job(RunOptions(scenario=LENSES, duration=70.0, fast=True, seed=2,
                                    view="none", db=str(db), faults=str(plan)))
    return db, report, truth, traces[0]


def truth_at(truth: dict[float, dict[str, str]], t: float) -> dict[str, str]:
    return truth[max(k for k in truth if k <= t + 1e-9)]


def replayed(db: Path, t: float) -> dict[str, str]:
    conn = open_readonly(db)
    view = read_trace(conn, 1)
    state = view.at(t)
    paths = node_paths(view)
    out = {paths[n.id]: STATUS_NAMES[state.statuses[n.id]] for n in view.nodes
           if n.tree == "feeding"}
    conn.close()
    return out


def test_the_run_faulted_and_recovered(fault_run):
    db, report, truth, _ = fault_run
    assert report["injected"].get("estop") == 1 and report["state"] == "STOPPED"
    faults = sqlite3.connect(db).execute(
        "SELECT t FROM events WHERE kind='fault' AND json_extract(data, '$.kind') IN "
        "('cell', 'estop')").fetchall()               # not the missed grips it recovered
    assert [round(t) for t, in faults] == [FAULT_AT]
    assert max(truth) > FAULT_AT + 10           # fed again after the reset


def test_replay_matches_the_live_trees_at_every_time(fault_run):
    db, _, truth, _ = fault_run
    times = sorted(truth)
    checked = 0
    for t in times[:: max(1, len(times) // 60)] + [times[-1]]:
        assert replayed(db, t) == truth_at(truth, t), t
        checked += 1
    assert checked > 30


def test_feeder_replay_before_the_fault(fault_run, capsys):
    db, _, truth, _ = fault_run
    assert main(["replay", str(db), "--before-fault", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    t = got["t"]
    assert t == pytest.approx(FAULT_AT - 1.0, abs=0.03)
    assert got["ticked"] == "feeding" and got["when"].startswith("1 s before the fault")
    want = truth_at(truth, t)
    assert {n["path"]: n["status"] for n in got["nodes"]} == want
    assert {"running", "success"} <= set(want.values())    # a tree doing something
    assert got["blackboard"]["/speeds/horizontal_mm_s"] > 0
    # the same as text: one line per node, each with the status it had
    assert main(["replay", str(db), "--before-fault"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"run 1 at t = {t:.2f} s (1 s before the fault")
    marks = {"running": "[*]", "success": "[✓]", "failure": "[✕]", "invalid": "[-]"}
    for n in got["nodes"]:
        assert f"{n['name']} {marks[n['status']]}" in "\n".join(lines), n
    # at the fault itself the e-stop halted every node: the replay says so too
    assert set(replayed(db, FAULT_AT + 0.5).values()) == {"invalid"}


def test_the_log_is_compact(fault_run):
    db, report, _, trace = fault_run
    conn = sqlite3.connect(db)
    (moves,), = conn.execute("SELECT sum(length(moves)) FROM tree_chunks").fetchall()
    assert trace.transitions > 300
    assert moves / trace.transitions <= MOVE_BYTES
    # what grows with the run's length: the chunks (the nodes are written once per run)
    (size,), = conn.execute("SELECT sum(length(base) + length(moves) + length(board) + 16) "
                            "FROM tree_chunks").fetchall()
    assert size / report["sim_seconds"] * 3600 < CHUNK_BYTES_PER_HOUR
    (nodes,), = conn.execute("SELECT count(*) FROM tree_nodes").fetchall()
    assert nodes == len(trace.nodes) < 400      # ids written once, kept across restarts


def test_replay_refuses_bad_times_in_one_line(fault_run, tmp_path, capsys):
    db, *_ = fault_run
    assert main(["replay", str(db), "--at", "9999"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "was recorded from 0.00 to" in err[0]
    quiet = tmp_path / "quiet.db"
    run_job(RunOptions(scenario=LENSES, duration=5.0, fast=True, view="none", db=str(quiet)))
    assert main(["replay", str(quiet), "--before-fault"]) == 2
    assert "had no fault" in capsys.readouterr().err
    assert main(["replay", str(quiet), "--at", "3"]) == 0
    assert "run 1 at t = 3.00 s" in capsys.readouterr().out


def test_status_codes_cover_py_trees():
    assert [s.value.lower() for s in (Status.INVALID, Status.RUNNING, Status.SUCCESS,
                                      Status.FAILURE)] == list(STATUS_NAMES)


def test_the_dashboards_memory_is_bounded_and_agrees_with_the_log(tmp_path, monkeypatch):
    """The live view (what the dashboard's timeline reads) keeps the newest chunks within
    MAX_LIVE_BYTES and shows the same states as the event log."""
    import feeder_bt.records.treelog as treelog
    monkeypatch.setattr(treelog, "MAX_LIVE_BYTES", 4000)
    traces: list[TreeTrace] = []
    orig = TreeTrace.__init__

    def live_init(self, cell, live=False, logged=True):
        orig(self, cell, live=True, logged=logged)
        traces.append(self)

    monkeypatch.setattr(TreeTrace, "__init__", live_init)
    db = tmp_path / "live.db"
    run_job(RunOptions(scenario=LENSES, duration=60.0, fast=True, seed=2, view="none",
                       db=str(db)))
    trace = traces[0]
    assert 0 < trace.live_bytes <= 4000 and len(trace.closed) == 0    # all written
    live = trace.publish()
    t0, t1 = live.span
    assert t0 > 10.0 and t1 >= 60.0                 # the oldest chunks were let go
    logged = read_trace(open_readonly(db), 1)
    assert logged.nodes == live.nodes and logged.span[0] == 0.0
    for t in (t0, (t0 + t1) / 2, t1 - 5.0):
        assert live.at(t).statuses == logged.at(t).statuses
        assert live.at(t).board == logged.at(t).board


def test_the_blackboard_panel_shows_values_for_people_not_python_reprs():
    """A frame on the blackboard reads as its figures; its image is never shown (nor
    copied), and no Python repr (``Frame(image=<ndarray>...``) reaches the panel."""
    import numpy as np

    from feeder_bt.hal.interfaces import Frame
    from feeder_bt.records.treelog import summarise

    shown = summarise(Frame(image=np.zeros((4, 4), np.uint8), latch=8012345, t=12.3, index=4))
    assert shown == "Frame: latch 8012345, t 12.3, index 4"
    assert "<" not in shown and "=" not in shown and "image" not in shown
