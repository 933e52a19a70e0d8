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
