"""PartsQueue: per-type FIFOs, oldest-head get, non-blocking leaves, wake on stop."""

from __future__ import annotations

import threading
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feeder_bt.core.parts import Part, PartsQueue

SAFETY_S = 30.0   # only a net against a hung test; nothing asserts on elapsed time


def mk(pid: int, type: str = "a", at: float | None = None, x: float = 0.0) -> Part:
    return Part(id=pid, type=type, x_mm=x, y_mm=0.0, angle_deg=0.0, latch=pid,
                located_at=float(pid) if at is None else at)


def ids(parts: list[Part]) -> list[int]:
    return [p.id for p in parts]


def wait_for_waiters(q: PartsQueue, n: int) -> None:
    """Block until ``n`` threads wait on the queue's condition (CPython internals)."""
    deadline = time.monotonic() + SAFETY_S
    while len(q._cond._waiters) < n:  # type: ignore[attr-defined]
        assert time.monotonic() < deadline, "waiter never blocked"
        time.sleep(0.001)


def start(target) -> tuple[threading.Thread, list]:
    out: list = []
    th = threading.Thread(target=lambda: out.append(target()), daemon=True)
    th.start()
    return th, out


# ---------------------------------------------------------------------------- basics


def test_empty_queue_non_blocking_get_returns_none():
    q = PartsQueue()
    assert q.get() is None
    assert q.get("a") is None
    assert len(q) == 0
    assert q.peek_all() == []


def test_single_type_is_fifo():
    q = PartsQueue()
    for i in (1, 2, 3):
        q.put(mk(i))
    assert ids([q.get(), q.get(), q.get()]) == [1, 2, 3]
    assert q.get() is None


def test_get_by_type_skips_other_types():
    q = PartsQueue()
    q.put(mk(1, "nut"))
    q.put(mk(2, "nut"))
    q.put(mk(3, "washer"))
    assert q.get("washer").id == 3
    assert q.get("washer") is None
    assert q.count("nut") == 2
    assert ids(q.peek_all()) == [1, 2]


def test_get_none_takes_oldest_head_by_time_then_id():
    q = PartsQueue()
    q.put(mk(5, "b", at=1.0))
    q.put(mk(4, "a", at=2.0))
    q.put(mk(3, "a", at=3.0))
    q.put(mk(2, "b", at=2.0))   # same time as id 4, lower id
    assert ids([q.get() for _ in range(4)]) == [5, 2, 4, 3]


def test_get_none_tie_on_time_and_id_prefers_earlier_type():
    q = PartsQueue(types=["b", "a"])
    q.put(mk(1, "a", at=0.0))
    q.put(mk(1, "b", at=0.0))
    assert q.get().type == "b"


def test_types_keep_declared_then_first_seen_order():
    q = PartsQueue(types=["lens", "square"])
    q.put(mk(1, "washer"))
    q.put(mk(2, "lens"))
    assert q.types == ("lens", "square", "washer")
    assert PartsQueue().types == ()


def test_put_front_goes_before_its_type_only():
    q = PartsQueue()
    q.put(mk(1, "a"))
    q.put(mk(2, "a"))
    back = mk(9, "a", at=0.5)
    q.put_front(back)
    assert q.get("a") is back
    assert q.get("a").id == 1


def test_put_front_of_a_returned_part_is_next_overall():
    q = PartsQueue()
    first = mk(1, "a", at=1.0)
    q.put(first)
    q.put(mk(2, "b", at=2.0))
    assert q.get() is first
    q.put_front(first)      # the pick was aborted; it is still the oldest
    assert q.get() is first


def test_count_and_len():
    q = PartsQueue()
    q.put(mk(1, "a"))
    q.put(mk(2, "b"))
    q.put(mk(3, "b"))
    assert len(q) == 3
    assert q.count("a") == 1
    assert q.count("b") == 2
    assert q.count("never") == 0


def test_get_unknown_type_does_not_create_a_type():
    q = PartsQueue()
    assert q.get("ghost") is None
    assert q.count("ghost") == 0
    assert q.types == ()


def test_peek_all_is_a_snapshot_oldest_first():
    q = PartsQueue()
    q.put(mk(3, "b", at=3.0))
    q.put(mk(1, "a", at=1.0))
    q.put(mk(2, "b", at=2.5))
    snap = q.peek_all()
    # FIFO within "b" is 3 then 2, so get() order (and the snapshot) is 1, 3, 2
    assert ids(snap) == [1, 3, 2]
    snap.clear()
    assert len(q) == 3


def test_remove_by_id():
    q = PartsQueue()
    for i in (1, 2, 3):
        q.put(mk(i, "a" if i != 2 else "b"))
    assert q.remove(2) is True
    assert q.remove(2) is False
    assert q.remove(42) is False
    assert ids(q.peek_all()) == [1, 3]


def test_take_removes_matching_and_keeps_the_rest_in_order():
    q = PartsQueue()
    for i, x in enumerate([10.0, 1200.0, 20.0, 1300.0, 30.0]):
        q.put(mk(i, "ab"[i % 2], x=x))
    gone = q.take(lambda p: p.x_mm > 1190.0)
    assert ids(gone) == [1, 3]
    assert ids(q.peek_all()) == [0, 2, 4]
    assert q.take(lambda p: False) == []


def test_flush_returns_everything_and_empties():
    q = PartsQueue()
    q.put(mk(1, "a"))
    q.put(mk(2, "b"))
    assert ids(q.flush()) == [1, 2]
    assert len(q) == 0
    assert q.flush() == []
    assert q.types == ("a", "b")   # the type order survives a flush


def test_version_changes_on_every_mutation_only():
    q = PartsQueue()
    v = q.version
    q.put(mk(1))
    assert q.version == v + 1
    q.put_front(mk(2))
    assert q.version == v + 2
    q.get()
    assert q.version == v + 3
    q.get("missing")
    q.peek_all()
    q.count("a")
    len(q)
    q.remove(999)
    q.take(lambda p: False)
    q.wake_all()
    assert q.version == v + 3
    assert q.remove(1)
    assert q.version == v + 4
    q.put(mk(3))
    q.put(mk(4))
    q.take(lambda p: True)
    assert q.version == v + 7
    q.flush()
    assert q.version == v + 7   # nothing to flush: no change
    q.put(mk(5))
    q.flush()
    assert q.version == v + 9


# ---------------------------------------------------------------------------- blocking


def test_blocking_get_times_out_with_none():
    q = PartsQueue()
    assert q.get(block=True, timeout=0.01) is None
    assert q.get("a", block=True, timeout=0.0) is None


def test_blocking_get_returns_immediately_when_a_part_is_there():
    q = PartsQueue()
    q.put(mk(1))
    assert q.get(block=True, timeout=SAFETY_S).id == 1


def test_wake_all_releases_a_blocked_get_with_none():
    q = PartsQueue()
    th, out = start(lambda: q.get(block=True))   # no timeout: only wake_all can free it
    wait_for_waiters(q, 1)
    q.wake_all()
    th.join(SAFETY_S)
    assert not th.is_alive()
    assert out == [None]


def test_wake_all_releases_every_waiter_typed_or_not():
    q = PartsQueue()
    threads = [start(lambda t=t: q.get(t, block=True)) for t in (None, "a", "b", None)]
    wait_for_waiters(q, len(threads))
    q.wake_all()
    for th, out in threads:
        th.join(SAFETY_S)
        assert not th.is_alive()
        assert out == [None]


def test_wake_all_does_not_poison_later_gets():
    q = PartsQueue()
    q.wake_all()
    q.put(mk(1))
    assert q.get(block=True, timeout=SAFETY_S).id == 1
    assert q.get(block=True, timeout=0.01) is None


def test_blocked_typed_get_waits_for_its_own_type():
    q = PartsQueue()
    th, out = start(lambda: q.get("washer", block=True, timeout=SAFETY_S))
    wait_for_waiters(q, 1)
    q.put(mk(1, "nut"))
    wait_for_waiters(q, 1)           # woken by the nut, went back to waiting
    assert q.count("nut") == 1
    q.put(mk(2, "washer"))
    th.join(SAFETY_S)
    assert not th.is_alive()
    assert ids(out) == [2]
    assert ids(q.peek_all()) == [1]


def test_blocked_untyped_get_receives_a_put_from_another_thread():
    q = PartsQueue()
    th, out = start(lambda: q.get(block=True, timeout=SAFETY_S))
    wait_for_waiters(q, 1)
    q.put(mk(7, "b"))
    th.join(SAFETY_S)
    assert ids(out) == [7]
    assert len(q) == 0


def test_concurrent_producers_and_consumers_lose_and_duplicate_nothing():
    q = PartsQueue()
    n_prod, per = 4, 250
    got: list[int] = []
    got_lock = threading.Lock()
    stop = threading.Event()

    def produce(k: int) -> None:
        for i in range(per):
            q.put(mk(k * per + i, "abc"[i % 3]))

    def consume(t: str | None) -> None:
        while not stop.is_set():
            p = q.get(t, block=True, timeout=SAFETY_S)
            if p is not None:
                with got_lock:
                    got.append(p.id)

    consumers = [threading.Thread(target=consume, args=(t,), daemon=True)
                 for t in (None, "a", "b", "c")]
    producers = [threading.Thread(target=produce, args=(k,)) for k in range(n_prod)]
    for th in consumers + producers:
        th.start()
    for th in producers:
        th.join(SAFETY_S)
    deadline = time.monotonic() + SAFETY_S
    while len(q) and time.monotonic() < deadline:
        time.sleep(0.001)
    stop.set()
    q.wake_all()
    for th in consumers:
        th.join(SAFETY_S)
        assert not th.is_alive()
    got.extend(ids(q.flush()))
    assert sorted(got) == list(range(n_prod * per))


# ---------------------------------------------------------------------------- model


class Model:
    """Reference: plain lists per type; get() scans the heads in type order."""

    def __init__(self) -> None:
        self.fifos: dict[str, list[Part]] = {}

    def put(self, p: Part) -> None:
        self.fifos.setdefault(p.type, []).append(p)

    def put_front(self, p: Part) -> None:
        self.fifos.setdefault(p.type, []).insert(0, p)

    def get(self, t: str | None) -> Part | None:
        if t is not None:
            f = self.fifos.get(t)
            return f.pop(0) if f else None
        best = None
        for f in self.fifos.values():
            if f and (best is None or (f[0].located_at, f[0].id) < (best[0].located_at,
                                                                    best[0].id)):
                best = f
        return best.pop(0) if best else None

    def all(self) -> list[Part]:
        copy = Model()
        copy.fifos = {t: list(f) for t, f in self.fifos.items()}
        out = []
        while (p := copy.get(None)) is not None:
            out.append(p)
        return out

    def flush(self) -> list[Part]:
        out = self.all()
        for f in self.fifos.values():
            f.clear()
        return out

    def remove(self, pid: int) -> bool:
        for f in self.fifos.values():
            for i, p in enumerate(f):
                if p.id == pid:
                    del f[i]
                    return True
        return False

    def take(self, limit: float) -> list[Part]:
        out = [p for p in self.all() if p.x_mm > limit]
        for t in self.fifos:
            self.fifos[t] = [p for p in self.fifos[t] if p.x_mm <= limit]
        return out


TYPES = st.sampled_from(["a", "b", "c"])
OPS = st.one_of(
    st.tuples(st.just("put"), TYPES, st.integers(0, 5), st.integers(0, 1300)),
    st.tuples(st.just("put_front"), TYPES, st.integers(0, 5), st.integers(0, 1300)),
    st.tuples(st.just("get"), st.none() | TYPES),
    st.tuples(st.just("flush")),
    st.tuples(st.just("remove"), st.integers(0, 40)),
    st.tuples(st.just("take"), st.integers(0, 1300)),
)


@settings(max_examples=300, deadline=None)
@given(types=st.permutations(["a", "b", "c"]) | st.none(), ops=st.lists(OPS, max_size=60))
def test_queue_matches_reference_model(types, ops):
    q = PartsQueue(types=types)
    m = Model()
    if types:
        for t in types:
            m.fifos[t] = []
    next_id = 0
    for op in ops:
        before = q.version
        changed: bool
        if op[0] in ("put", "put_front"):
            # few distinct times so ties on located_at are common
            p = mk(next_id, op[1], at=float(op[2]), x=float(op[3]))
            next_id += 1
            getattr(q, op[0])(p)
            getattr(m, op[0])(p)
            changed = True
        elif op[0] == "get":
            got, want = q.get(op[1]), m.get(op[1])
            assert got is want
            changed = want is not None
        elif op[0] == "flush":
            got, want = q.flush(), m.flush()
            assert ids(got) == ids(want)
            changed = bool(want)
        elif op[0] == "remove":
            got, want = q.remove(op[1]), m.remove(op[1])
            assert got == want
            changed = want
        else:
            got, want = q.take(lambda p, lim=op[1]: p.x_mm > lim), m.take(op[1])
            assert ids(got) == ids(want)
            changed = bool(want)
        assert (q.version != before) == changed
        assert ids(q.peek_all()) == ids(m.all())
        assert len(q) == sum(len(f) for f in m.fifos.values())
        for t in ("a", "b", "c"):
            assert q.count(t) == len(m.fifos.get(t, []))
        assert list(q.types) == list(m.fifos)


@pytest.mark.parametrize("t", [None, "a"])
def test_get_after_flush_is_none(t):
    q = PartsQueue()
    q.put(mk(1, "a"))
    q.flush()
    assert q.get(t) is None
