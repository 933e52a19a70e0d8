"""The connection gate's rules, on stand-in transports (no sockets): eviction comes
before refusal, oldest idle first, the reserve owner's connections are never displaced,
and a newcomer finding every connection busy goes on trial in the reserve."""

from __future__ import annotations

from feeder_bt.control.conns import ConnGate, ConnLimits


class FakeTransport:
    def __init__(self, ip: str = "127.0.0.1", port: int = 1) -> None:
        self.peer = (ip, port)
        self.aborted = False

    def get_extra_info(self, key: str):
        return self.peer if key == "peername" else None

    def abort(self) -> None:
        self.aborted = True


def gate(**kw) -> ConnGate:
    return ConnGate("test", ConnLimits(**kw), say=lambda line: None)


def test_over_the_per_address_cap_the_oldest_idle_one_from_that_address_makes_room():
    g = gate(total=100, per_address=3)
    other = FakeTransport("10.0.0.9")
    assert g.admit(other, lambda: False)
    mine = [FakeTransport(port=i) for i in range(3)]
    busy = {0: True}
    for i, t in enumerate(mine):
        assert g.admit(t, lambda i=i: busy.get(i, False))
    new = FakeTransport(port=9)
    assert g.admit(new, lambda: False)
    # mine[0] is busy (a request in flight): mine[1], the oldest idle one, made room
    assert not mine[0].aborted and mine[1].aborted and not mine[2].aborted
    assert not other.aborted                      # another address is not touched
    assert g.stats()["evicted"] == 1 and g.stats().get("refused", 0) == 0


def test_the_owner_s_connections_are_never_displaced_and_sit_outside_the_caps():
    g = gate(total=100, per_address=2, reserve=4)
    holder = {"on": True}
    ws = FakeTransport(port=1)
    assert g.admit(ws, lambda: False)            # an open websocket is idle ...
    assert g.vouch(ws, lambda: holder["on"])      # ... but the holder of control's
    idle = [FakeTransport(port=10 + i) for i in range(2)]
    for t in idle:
        assert g.admit(t, lambda: False)          # the caps still take two more
    for i in range(5):
        assert g.admit(FakeTransport(port=20 + i), lambda: False)
    assert not ws.aborted and g.stats()["reserve_open"] == 1
    holder["on"] = False                          # she released control: no longer kept
    g.release(ws)
    assert g.stats()["reserve_open"] == 0


def test_when_every_connection_is_busy_a_newcomer_is_on_trial_then_refused():
    g = gate(total=100, per_address=2, reserve=2)
    for i in range(2):
        assert g.admit(FakeTransport(port=i), lambda: True)     # requests in flight
    first = FakeTransport(port=10)
    assert g.admit(first, lambda: False) and g.on_trial(first)
    second = FakeTransport(port=11)              # one on trial at most (half the reserve)
    assert g.admit(second, lambda: False)        # ... the idle one on trial made room
    assert first.aborted and g.on_trial(second)
    assert g.vouch(second, lambda: True) and not g.on_trial(second)
    third = FakeTransport(port=12)
    assert g.admit(third, lambda: True) and g.on_trial(third)   # busy, on trial
    fourth = FakeTransport(port=13)
    assert not g.admit(fourth, lambda: False) and fourth.aborted
    assert g.stats()["refused"] == 1
    for t in (second, third):
        g.release(t)
    assert g.stats()["open"] == 2 and g.stats()["reserve_open"] == 0


def test_without_a_reserve_a_full_address_of_busy_connections_refuses():
    g = gate(total=100, per_address=1)
    assert g.admit(FakeTransport(port=1), lambda: True)
    late = FakeTransport(port=2)
    assert not g.admit(late, lambda: False) and late.aborted


def test_with_a_lobby_silent_connections_never_displace_one_that_spoke():
    g = gate(total=100, per_address=2, lobby=8)
    client = FakeTransport(port=1)
    assert g.admit(client, lambda: False) and g.heard(client)   # its Hello: in the caps
    flood = [FakeTransport(port=100 + i) for i in range(50)]     # silent, same address
    for t in flood:
        assert g.admit(t, lambda: False)
    assert not client.aborted
    assert sum(not t.aborted for t in flood) == 8                # the lobby's size
    assert all(t.aborted for t in flood[:42])                    # the oldest made room
    assert g.stats()["lobby_open"] == 8 and g.stats()["open"] == 9


def test_a_silent_client_outlasts_one_lobby_less_one_of_newer_silent_ones():
    """The bound the design gives: a client not yet heard from is closed only after
    ``lobby`` newer silent connections from its own (heaviest) address."""
    g = gate(total=100, per_address=2, lobby=8)
    flood = [FakeTransport(port=100 + i) for i in range(7)]
    for t in flood:
        assert g.admit(t, lambda: False)
    client = FakeTransport(port=1)
    assert g.admit(client, lambda: False)
    later = [FakeTransport(port=200 + i) for i in range(7)]
    for t in later:
        assert g.admit(t, lambda: False)
    assert not client.aborted and all(t.aborted for t in flood)
    assert g.heard(client) and not g.on_trial(client)           # in the caps now
    for i in range(100):
        assert g.admit(FakeTransport(port=300 + i), lambda: False)
    assert not client.aborted


def test_a_full_lobby_makes_room_from_the_address_holding_the_most():
    g = gate(total=100, per_address=2, lobby=4)
    client = FakeTransport("10.0.0.2", port=1)
    assert g.admit(client, lambda: False)
    flood = [FakeTransport("10.0.0.1", port=100 + i) for i in range(40)]
    for t in flood:
        assert g.admit(t, lambda: False)
    assert not client.aborted and sum(not t.aborted for t in flood) == 3


def test_a_connection_that_speaks_over_the_cap_closes_the_oldest_idle_one_that_spoke():
    g = gate(total=100, per_address=2, lobby=8)
    busy = {"a": False}
    a, b, c, d = (FakeTransport(port=i) for i in range(4))
    assert g.admit(a, lambda: busy["a"]) and g.admit(b, lambda: True)
    assert g.heard(a) and g.heard(b)
    assert g.admit(c, lambda: False) and not a.aborted           # silent: in the lobby
    assert g.heard(c) and a.aborted and not b.aborted            # a idle, b busy
    busy["a"] = True
    assert g.admit(d, lambda: False) and g.heard(b)             # heard again: no change
    assert g.stats()["lobby_open"] == 1
    g.release(c)
    e = FakeTransport(port=5)
    assert g.admit(e, lambda: True) and g.heard(e)               # room again (c left)
    assert not g.heard(d) and d.aborted                          # b, e busy; no reserve
    assert g.stats()["refused"] == 1 and g.stats()["open"] == 2


def test_a_lobby_of_busy_connections_refuses_a_newcomer():
    g = gate(total=100, per_address=2, lobby=2)
    for i in range(2):
        assert g.admit(FakeTransport(port=i), lambda: True)
    late = FakeTransport(port=9)
    assert not g.admit(late, lambda: False) and late.aborted


def test_a_robot_vouched_for_in_the_lobby_enters_the_caps_when_it_speaks_never_on_trial():
    """A robot known by its address is vouched for when it connects; with the reserve full
    it waits in the lobby, kept. When it speaks it takes the reserve if there is room, else
    a place in the caps: never a trial (the listener would close it at a first line that is
    not HELLO) and never a refusal, even with every capped connection busy."""
    g = gate(total=8, per_address=8, reserve=1, lobby=4)     # 8: the gate's least total
    owner = FakeTransport(port=1)
    assert g.admit(owner, lambda: True) and g.heard(owner)
    assert g.vouch(owner, lambda: True)                      # the reserve's one place
    for i in range(8):                                       # the caps, all busy
        t = FakeTransport(port=10 + i)
        assert g.admit(t, lambda: True) and g.heard(t)
    robot = FakeTransport("10.0.0.7", port=5)
    assert g.admit(robot, lambda: False)                     # silent: in the lobby
    assert not g.vouch(robot, lambda: True)                  # the reserve is full: kept
    assert g.heard(robot) and not robot.aborted
    assert not g.on_trial(robot)
    stranger = FakeTransport("10.0.0.8", port=6)
    assert g.admit(stranger, lambda: False)
    assert not g.heard(stranger) and stranger.aborted        # a stranger is still refused


def test_the_reserve_the_caps_and_the_lobby_share_one_descriptor_budget(monkeypatch):
    """With few file descriptors to spare, the reserve (the owner's), the caps and the lobby
    together never hold more connections than the budget, the reserve kept whole."""
    from feeder_bt.control import conns
    monkeypatch.setattr(conns, "raise_fd_limit", lambda want=65536: 64 + 2 * 300)
    g = ConnGate("test", ConnLimits(total=256, reserve=4, lobby=1000), say=lambda line: None)
    assert g.reserve == 4 and g.total == 256
    assert g.reserve + g.total + g.lobby == 300
    monkeypatch.setattr(conns, "raise_fd_limit", lambda want=65536: 64 + 2 * 100)
    g = ConnGate("test", ConnLimits(total=256, reserve=4, lobby=1000), say=lambda line: None)
    assert (g.reserve, g.total, g.lobby) == (4, 96, 8)        # the lobby's floor of 8
