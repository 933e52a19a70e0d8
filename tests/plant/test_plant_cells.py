"""Many cells: two simulated cells in two processes, each serving OPC UA, both
supervised from one client — counts read from both, one stopped, the other feeding on."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("asyncua")

from asyncua import Client  # noqa: E402

from feeder_bt.control.users import UsersFile  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 90.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_cell(tmp: Path, name: str, port: int, users: Path, seed: int) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "feeder_bt.cli", "run", "scenarios/lenses.yaml",
         "--seed", str(seed), "--view", "none", "--no-db", "--duration", "600",
         "--opcua", f"127.0.0.1:{port}", "--opcua-insecure", "--opcua-pki", str(tmp / name),
         "--users", str(users), "--report", str(tmp / f"{name}.json")],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


async def connect(url: str) -> Client:
    t_end = time.monotonic() + WAIT_S
    while True:
        c = Client(url, timeout=20)
        c.set_user("alice")
        c.set_password("alice-pass-1")
        try:
            await c.connect()
            return c
        except (TimeoutError, OSError):
            if time.monotonic() > t_end:
                raise
            await asyncio.sleep(0.3)


async def value(c: Client, *path: str):
    idx = await c.get_namespace_index("urn:feeder_bt")
    node = await c.nodes.objects.get_child([f"{idx}:Cell", *(f"{idx}:{p}" for p in path)])
    return await node.read_value()


async def until(c: Client, path: tuple[str, ...], ok) -> object:
    t_end = time.monotonic() + WAIT_S
    while True:
        v = await value(c, *path)
        if ok(v) or time.monotonic() > t_end:
            return v
        await asyncio.sleep(0.2)


@pytest.mark.soak      # real time: two cells in two processes
def test_two_cells_in_two_processes_supervised_from_one_client(tmp_path):
    users = tmp_path / "users.json"
    UsersFile(users).add("alice", "alice-pass-1")
    ports = {"east": free_port(), "west": free_port()}
    procs = {name: start_cell(tmp_path, name, port, users, seed)
             for (name, port), seed in zip(ports.items(), (1, 2), strict=True)}
    try:
        async def supervise() -> dict[str, object]:
            cells = {name: await connect(f"opc.tcp://127.0.0.1:{port}/feeder")
                     for name, port in ports.items()}
            try:
                for c in cells.values():
                    assert await until(c, ("State",), lambda s: s == "RUNNING") == "RUNNING"
                    assert await value(c, "Scenario") == "lenses"
                # counts from both: each cell's own, and both locate parts
                located = {n: await until(c, ("Counters", "Located"), lambda v: v > 0)
                           for n, c in cells.items()}
                assert all(v > 0 for v in located.values())
                west = cells["west"]
                idx = await west.get_namespace_index("urn:feeder_bt")
                cell = await west.nodes.objects.get_child(f"{idx}:Cell")
                await cell.call_method(f"{idx}:TakeControl")
                await cell.call_method(f"{idx}:Stop")
                assert await until(west, ("State",), lambda s: s == "STOPPED") == "STOPPED"
                assert await value(cells["east"], "State") == "RUNNING"
                return located
            finally:
                for c in cells.values():
                    await c.disconnect()

        asyncio.run(supervise())
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)        # an orderly stop, then the report
        outs = {name: p.communicate(timeout=120) for name, p in procs.items()}
    for name, p in procs.items():
        assert p.returncode == 0, outs[name][1][-2000:]
    east, west = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("east", "west"))
    assert east["parts"]["lost"] == 0 and west["parts"]["lost"] == 0
    assert [c["action"] for c in west["opcua"]["commands"]
            if c["action"] in ("start", "stop")] == ["stop"]
    assert not [c for c in east["opcua"]["commands"] if c["action"] == "stop"]
