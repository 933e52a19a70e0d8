"""Encoder sync: 32-bit conveyor counts to 24-bit robot counts across roll-over."""

from __future__ import annotations

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from feeder_bt.core.encoder import EncoderSync, diff, wrap

I32_MIN, I32_MAX = -(2**31), 2**31 - 1
I24_MIN, I24_MAX = -(2**23), 2**23 - 1
BITS = st.integers(1, 64)
BIG = st.integers(-(2**70), 2**70)


# ---------------------------------------------------------------------------- wrap / diff


@pytest.mark.parametrize(
    ("value", "bits", "expected"),
    [
        (0, 24, 0),
        (I24_MAX, 24, I24_MAX),
        (I24_MAX + 1, 24, I24_MIN),
        (I24_MIN - 1, 24, I24_MAX),
        (2**24, 24, 0),
        (-(2**24), 24, 0),
        (I32_MAX + 1, 32, I32_MIN),
        (I32_MIN, 32, I32_MIN),
        (5, 2, 1),    # 2-bit counter holds -2..1
        (2, 2, -2),
        (1, 1, -1),   # 1-bit counter holds -1..0
    ],
)
def test_wrap_examples(value, bits, expected):
    assert wrap(value, bits) == expected


@pytest.mark.parametrize("bits", [0, -3])
def test_wrap_rejects_nonpositive_width(bits):
    with pytest.raises(ValueError):
        wrap(1, bits)


@given(BIG, BITS)
def test_wrap_lands_in_range_and_is_congruent(v, bits):
    w = wrap(v, bits)
    assert -(2 ** (bits - 1)) <= w < 2 ** (bits - 1)
    assert (w - v) % (2**bits) == 0


@given(BIG, BITS)
def test_wrap_is_idempotent(v, bits):
    assert wrap(wrap(v, bits), bits) == wrap(v, bits)


@given(st.integers(-(2**40), 2**40), BITS)
def test_wrap_is_identity_inside_range(v, bits):
    assume(-(2 ** (bits - 1)) <= v < 2 ** (bits - 1))
    assert wrap(v, bits) == v


@pytest.mark.parametrize(
    ("a", "b", "bits", "expected"),
    [
        (I24_MIN, I24_MAX, 24, 1),      # one count forward across the wrap
        (I24_MAX, I24_MIN, 24, -1),     # one count backward across the wrap
        (10, 3, 24, 7),
        (3, 10, 24, -7),
        (I32_MIN + 5, I32_MAX - 4, 32, 10),
    ],
)
def test_diff_examples(a, b, bits, expected):
    assert diff(a, b, bits) == expected


@given(BIG, st.integers(-(2**40), 2**40), st.integers(2, 48))
def test_diff_recovers_any_move_under_half_a_wrap(start, move, bits):
    assume(-(2 ** (bits - 1)) <= move < 2 ** (bits - 1))
    assert diff(wrap(start + move, bits), wrap(start, bits), bits) == move


@given(BIG, BIG, BITS)
def test_diff_identities(a, b, bits):
    d = diff(a, b, bits)
    assert wrap(b + d, bits) == wrap(a, bits)
    assert diff(a, a, bits) == 0
    assert diff(wrap(a, bits), wrap(b, bits), bits) == d
    # antisymmetric except at exactly half a wrap, which has one representation
    if d != -(2 ** (bits - 1)):
        assert diff(b, a, bits) == -d


# ---------------------------------------------------------------------------- EncoderSync


def test_to_robot_before_reset_raises():
    sync = EncoderSync()
    assert not sync.is_reset
    assert sync.reference is None
    with pytest.raises(RuntimeError):
        sync.to_robot(0)


def test_rejects_silly_widths():
    with pytest.raises(ValueError):
        EncoderSync(conveyor_bits=1)


def test_reset_wraps_and_records_reference():
    sync = EncoderSync()
    sync.reset(2**31, 2**23 + 5)
    assert sync.is_reset
    assert sync.reference == (I32_MIN, I24_MIN + 5)


def test_to_robot_simple_offset():
    sync = EncoderSync()
    sync.reset(1000, -50)
    assert sync.to_robot(1000) == -50
    assert sync.to_robot(1100) == 50
    assert sync.reference == (1100, 50)


def test_to_robot_across_robot_wrap():
    sync = EncoderSync()
    sync.reset(0, I24_MAX - 9)
    assert sync.to_robot(10) == I24_MIN
    assert sync.to_robot(2**24 + 10) == I24_MIN   # a whole robot wrap later


def test_to_robot_across_conveyor_wrap():
    sync = EncoderSync()
    sync.reset(I32_MAX - 4, 0)
    assert sync.to_robot(I32_MIN + 5) == 10


def test_older_latch_translates_without_moving_reference_back():
    sync = EncoderSync()
    sync.reset(0, 0)
    assert sync.to_robot(500) == 500
    assert sync.to_robot(300) == 300        # a latch from an earlier frame
    assert sync.reference == (500, 500)
    assert sync.to_robot(600) == 600


def test_latch_before_a_robot_wrap_still_translates_after_it():
    sync = EncoderSync()
    sync.reset(0, I24_MAX - 100)
    latched = 50                                 # robot count I24_MAX - 50
    assert sync.to_robot(1000) == I24_MIN + 899  # belt moved on, robot wrapped
    assert sync.to_robot(latched) == I24_MAX - 50


def test_robot_diff_and_mm_between():
    sync = EncoderSync()
    assert sync.robot_diff(I24_MIN + 5, I24_MAX - 4) == 10
    assert sync.robot_diff(I24_MAX - 4, I24_MIN + 5) == -10
    assert sync.mm_between(I24_MIN + 5, I24_MAX - 4, counts_per_mm=4.0) == 2.5
    assert sync.mm_between(100, 140, counts_per_mm=8.0) == -5.0
    with pytest.raises(ValueError):
        sync.mm_between(1, 0, counts_per_mm=0)


def test_custom_widths():
    sync = EncoderSync(conveyor_bits=16, robot_bits=8)
    sync.reset(32760, 120)
    assert sync.to_robot(-32766) == wrap(120 + 10, 8)


# A move is mostly forward, sometimes backward by less than half a robot wrap; each is
# far below half a 32-bit wrap, so calling to_robot after every move must stay exact.
MOVES = st.lists(
    st.one_of(
        st.integers(0, 3 * 2**23),                 # up to 1.5 robot wraps in one go
        st.integers(0, 2**30),                     # big jumps: conveyor wraps happen too
        st.integers(-(2**22), 0),                  # occasional backward jog
    ),
    min_size=1,
    max_size=80,
)
NEAR_32 = st.one_of(st.integers(I32_MIN, I32_MAX), st.integers(I32_MAX - 2**24, I32_MAX),
                    st.integers(I32_MIN, I32_MIN + 2**24))
NEAR_24 = st.one_of(st.integers(I24_MIN, I24_MAX), st.integers(I24_MAX - 1000, I24_MAX))


def test_gap_longer_than_half_the_larger_counter_loses_sync():
    """The documented limit (thesis 5.3.1), visible when the conveyor counter is the
    narrower one: a gap over half its wrap is read as a move the other way."""
    sync = EncoderSync(conveyor_bits=16, robot_bits=24)
    sync.reset(0, 0)
    moved = 2**15 + 10          # more than half a 16-bit wrap without a call
    assert sync.to_robot(wrap(moved, 16)) != wrap(moved, 24)
    sync.reset(0, 0)
    sync.to_robot(2**14)        # one call in between keeps it right
    assert sync.to_robot(wrap(moved, 16)) == wrap(moved, 24)


@given(NEAR_32, NEAR_24, st.integers(0, 2**40))
def test_default_widths_survive_any_gap(conv_start, robot_start, moved):
    """2**24 divides 2**32, so a 32-bit difference is exact modulo the robot's wrap."""
    sync = EncoderSync()
    sync.reset(conv_start, robot_start)
    assert sync.to_robot(wrap(conv_start + moved, 32)) == wrap(robot_start + moved, 24)


@settings(max_examples=300)
@given(NEAR_32, NEAR_24, MOVES)
def test_to_robot_tracks_belt_through_many_wraps(conv_start, robot_start, moves):
    sync = EncoderSync()
    sync.reset(conv_start, robot_start)
    total = 0
    for m in moves:
        total += m
        conv = wrap(conv_start + total, 32)
        assert sync.to_robot(conv) == wrap(robot_start + total, 24)


@settings(max_examples=300)
@given(NEAR_32, NEAR_24, MOVES, st.data())
def test_latched_counts_translate_after_the_belt_moves_on(conv_start, robot_start, moves,
                                                          data):
    """A latch taken mid-run and translated later (still within half a conveyor wrap)."""
    sync = EncoderSync()
    sync.reset(conv_start, robot_start)
    latch_at = data.draw(st.integers(0, len(moves) - 1))
    total = 0
    latch = None
    for i, m in enumerate(moves):
        total += m
        if i == latch_at:
            latch = (wrap(conv_start + total, 32), wrap(robot_start + total, 24), total)
        sync.to_robot(wrap(conv_start + total, 32))
    assert latch is not None
    assume(abs(total - latch[2]) < 2**31)
    assert sync.to_robot(latch[0]) == latch[1]


@settings(max_examples=200)
@given(NEAR_32, NEAR_24, st.lists(st.integers(0, 2**30), min_size=1, max_size=20))
def test_wrapped_and_unwrapped_inputs_agree(conv_start, robot_start, moves):
    a, b = EncoderSync(), EncoderSync()
    a.reset(conv_start, robot_start)
    b.reset(conv_start + 2**32, robot_start - 2**24)   # same counters, unreduced
    total = 0
    for m in moves:
        total += m
        assert a.to_robot(wrap(conv_start + total, 32)) == b.to_robot(conv_start + total)
