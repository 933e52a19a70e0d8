"""Galil protocol, pure: the reply/unsolicited splitter, numbers, errors, command
formatting and download preparation. No sockets, no threads."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feeder_bt.core.errors import CommsLost, HalError
from feeder_bt.hal.galil.driver import PROGRAMS_DIR
from feeder_bt.hal.galil.protocol import (
    MAX_LABELS,
    MAX_LINE_CHARS,
    MAX_PROGRAM_LINES,
    CardEvent,
    DistanceEvent,
    DownloadError,
    GalilError,
    InputsEvent,
    Message,
    ProgramError,
    ProtocolError,
    Reply,
    ReplySplitter,
    Unsolicited,
    axes_command,
    download_payload,
    explicit,
    parse_int,
    parse_number,
    parse_numbers,
    parse_tell_code,
    parse_unsolicited,
    positional,
    prepare_download,
    prepare_lines,
    read_programs,
    strip_comment,
)


def hi(text: str) -> bytes:
    """Unsolicited bytes as under CW 1: top bit set."""
    return bytes(b | 0x80 for b in text.encode("ascii"))


def feed_all(chunks) -> list:
    sp = ReplySplitter()
    out = []
    for c in chunks:
        out += sp.feed(c)
    return out


# ---------------------------------------------------------------------------- splitter


def test_replies_and_rejection():
    out = feed_all([b":", b" 1234\r\n:", b"?", b"1 Unrecognized command\r\n:"])
    assert out == [Reply(True, ""), Reply(True, " 1234"), Reply(False),
                   Reply(True, "1 Unrecognized command")]


def test_colon_inside_data_does_not_end_a_reply():
    assert feed_all([b"12:30 ok\r\n:"]) == [Reply(True, "12:30 ok")]


STREAM = b" 1234\r\n:" + hi("D 0000000100\r\n") + b":?" + b"a, b\r\n:"


def test_unsolicited_in_the_middle_of_a_reply_every_split_point():
    # unsolicited bytes arrive half-way through " 1234\r\n:"
    stream = b" 12" + hi("I 005\r\n") + b"34\r\n:" + hi("D 00") + b":" + hi("12\r\n")
    # each item comes out when its last byte arrives
    expected = [Unsolicited("I 005"), Reply(True, " 1234"), Reply(True, ""),
                Unsolicited("D 0012")]
    for cut in range(len(stream) + 1):
        assert feed_all([stream[:cut], stream[cut:]]) == expected


def test_byte_by_byte_and_all_chunk_sizes():
    expected = feed_all([STREAM])
    assert expected == [Reply(True, " 1234"), Unsolicited("D 0000000100"), Reply(True, ""),
                        Reply(False), Reply(True, "a, b")]
    for size in range(1, len(STREAM) + 1):
        chunks = [STREAM[i:i + size] for i in range(0, len(STREAM), size)]
        assert feed_all(chunks) == expected


def test_runaway_reply_is_a_protocol_error_not_a_crash():
    sp = ReplySplitter(max_reply=16)
    with pytest.raises(ProtocolError):
        sp.feed(b"x" * 17)
    assert isinstance(ProtocolError("x"), CommsLost)
    sp.reset()
    assert sp.feed(b" 1\r\n:") == [Reply(True, " 1")]
    with pytest.raises(ProtocolError):
        ReplySplitter(max_reply=4).feed(hi("abcdef"))


def test_garbage_bytes_never_raise_decode_errors():
    out = feed_all([bytes([0x01, 0x7F, 0x0D, 0x0A, 0x3A])])
    assert out == [Reply(True, "\x01\x7f")]
    assert feed_all([bytes([0xFF, 0x8A])]) == [Unsolicited("\x7f")]


DATA = st.text(alphabet="ABCXYZ0123456789 ,.-:?", max_size=12).filter(
    lambda s: not s or s[0] not in ":?")
ITEMS = st.lists(st.one_of(
    st.builds(lambda d: ("reply", d), DATA),
    st.just(("reject", "")),
    st.builds(lambda d: ("msg", d), st.text(alphabet="ID 0123456789:?abc", max_size=12)),
), max_size=12)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(items=ITEMS, data=st.data())
def test_property_any_interleaving_any_chunking(items, data):
    """Replies come out in order and intact, and so do unsolicited lines, however the
    unsolicited bytes are interleaved with reply bytes and however the stream is cut."""
    solicited = bytearray()
    unsolicited = bytearray()
    want_replies, want_lines = [], []
    for kind, text in items:
        if kind == "reply":
            solicited += (text + "\r\n:").encode() if text else b":"
            want_replies.append(Reply(True, text.strip("\r\n")))
        elif kind == "reject":
            solicited += b"?"
            want_replies.append(Reply(False))
        else:
            unsolicited += hi(text + "\r\n")
            want_lines.append(Unsolicited(text))
    # interleave: at each step take the next byte of one stream or the other
    choices = data.draw(st.lists(st.booleans(), min_size=len(solicited) + len(unsolicited),
                                 max_size=len(solicited) + len(unsolicited)))
    stream, i, j = bytearray(), 0, 0
    for pick_unsolicited in choices:
        if (pick_unsolicited and j < len(unsolicited)) or i >= len(solicited):
            stream.append(unsolicited[j])
            j += 1
        else:
            stream.append(solicited[i])
            i += 1
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    bounds = [0, *cuts, len(stream)]
    out = feed_all([bytes(stream[a:b]) for a, b in zip(bounds, bounds[1:], strict=False)])
    assert [o for o in out if isinstance(o, Reply)] == want_replies
    assert [o for o in out if isinstance(o, Unsolicited)] == want_lines


# ---------------------------------------------------------------------------- numbers, errors


@pytest.mark.parametrize(("text", "value"), [
    (" 1234", 1234.0), ("-5.0000", -5.0), ("0", 0.0), (" 1.5", 1.5), ("$FF", 255.0),
    (".5", 0.5), ("+7", 7.0)])
def test_parse_number(text, value):
    assert parse_number(text) == value


@pytest.mark.parametrize("text", ["", "abc", "1.2.3", "nan", "inf", "1e5", "?", "--1", "$",
                                  "$XYZ", "\x00"])
def test_garbage_numbers_raise_typed_errors(text):
    with pytest.raises(ProtocolError):
        parse_number(text)


def test_parse_int_and_lists():
    assert parse_int(" 99.6") == 100
    assert parse_numbers(" 100, -200") == [100.0, -200.0]
    with pytest.raises(CommsLost):
        parse_numbers(" 1,,2")
    with pytest.raises(ProtocolError):
        parse_number(None)        # type: ignore[arg-type]


def test_tell_code_and_galil_error():
    assert parse_tell_code("1 Unrecognized command\r\n") == (1, "Unrecognized command")
    assert parse_tell_code("22") == (22, "Begin not possible due to Limit Switch")
    assert parse_tell_code("") == (-1, "unknown error (empty TC1 reply)")
    assert parse_tell_code("garbage") == (-1, "garbage")
    e = GalilError(1, "Unrecognized command", command="XX")
    assert isinstance(e, HalError) and e.code == 1 and e.text == "Unrecognized command"
    assert "XX" in str(e) and e.kind == "galil"


def test_parse_unsolicited():
    assert parse_unsolicited("I 005") == InputsEvent(5)
    assert parse_unsolicited("D 0000012345") == DistanceEvent(12345)
    assert parse_unsolicited("D-0000000020") == DistanceEvent(-20)
    assert parse_unsolicited("?042 JX 1") == ProgramError("042 JX 1")
    assert parse_unsolicited("Hello") == Message("Hello")
    assert parse_unsolicited("I 09999") == InputsEvent(9999)        # inputs 1-16
    assert parse_unsolicited("I 70000") == Message("I 70000")        # more than 16 bits
    assert parse_unsolicited("D xyz") == Message("D xyz")
    assert parse_unsolicited("") == Message("")


@pytest.mark.parametrize("line", ["?042 JX 1", "004 JX 1?", "  12 XQ #NONE,1?", "JP #NOWHERE?"])
def test_program_errors_in_every_echo_form(line):
    """Finding 4: the card echoes a failed program line with the '?' in more than one
    place; every form is a ProgramError, never a Message nobody looks at."""
    assert isinstance(parse_unsolicited(line), ProgramError)


def test_card_events():
    assert parse_unsolicited("E POSERR") == CardEvent("POSERR")
    assert parse_unsolicited("E CMDERR 1 0012") == CardEvent("CMDERR", "1 0012")
    assert parse_unsolicited("W") == CardEvent("WATCHDOG")
    assert parse_unsolicited("E NOTHING") == Message("E NOTHING")


def test_an_echoed_bare_cr_does_not_leave_a_reply_incomplete():
    """Finding 8: a serial port echoes the command and its CR before the ':'."""
    sp = ReplySplitter()
    assert sp.feed(b"EO 0\r:") == [Reply(True, "EO 0")]
    assert sp.feed(b"CW 1\r:") == [Reply(True, "CW 1")]
    assert sp.feed(b"XX\r?") == [Reply(False)]              # a rejection after its echo
    assert sp.pending == b""


# ---------------------------------------------------------------------------- commands


def test_command_formatting():
    assert positional("PR", {"B": 500}) == "PR ,500"
    assert positional("JG", {"A": -20, "C": 2.5}) == "JG -20,,2.5"
    assert explicit("SP", "B", 2000) == "SPB=2000"
    assert axes_command("BG", "B") == "BGB"
    assert axes_command("SH", "ab") == "SHAB"
    for bad in (lambda: positional("PR", {"Z": 1}), lambda: explicit("SP", "BB", 1),
                lambda: positional("PR", {}), lambda: explicit("SP", "A", float("nan"))):
        with pytest.raises(GalilError):
            bad()


# ---------------------------------------------------------------------------- download


def test_comments_and_blank_lines_are_stripped():
    text = "REM header\n\n  #A  \n NO comment\n MG \"it's\" ' says it\n' whole line\nJP #A;\nEN"
    lines = prepare_lines(text, "t.dmc")
    assert [(pl.text, pl.line) for pl in lines] == [
        ("#A", 3), ('MG "it\'s"', 5), ("JP #A", 7), ("EN", 8)]
    assert strip_comment("REMAIN=1") == "REMAIN=1"
    assert strip_comment("NOTE=1") == "NOTE=1"


def test_over_long_line_names_file_and_line():
    text = "#A\n" + "MG \"" + "x" * MAX_LINE_CHARS + "\"\nEN\n"
    with pytest.raises(DownloadError) as err:
        prepare_lines(text, "galil_programs/long.dmc")
    assert err.value.file == "galil_programs/long.dmc" and err.value.line == 2
    assert "galil_programs/long.dmc:2:" in str(err.value) and "80" in str(err.value)
    assert isinstance(err.value, GalilError)
    # exactly 80 characters is fine; the comment does not count
    ok = "MG \"" + "x" * (MAX_LINE_CHARS - 6) + "\"" + "   ' a long comment " + "y" * 80
    assert len(prepare_lines(ok)[0].text) == MAX_LINE_CHARS - 1


@pytest.mark.parametrize(("label", "ok"), [
    ("#A", True), ("#LOOP7", True), ("#ABCDEFG", True), ("#ABCDEFGH", False),
    ("#1A", False), ("#A_B", False), ("#", False)])
def test_label_rules(label, ok):
    if ok:
        assert prepare_lines(label)[0].text == label
    else:
        with pytest.raises(DownloadError) as err:
            prepare_lines(f"EN\n{label}\n", "x.dmc")
        assert err.value.line == 2 and err.value.code == 61


def test_too_many_lines_and_duplicate_labels_across_files():
    with pytest.raises(DownloadError) as err:
        prepare_download([("big.dmc", "EN\n" * (MAX_PROGRAM_LINES + 1))])
    assert err.value.line == MAX_PROGRAM_LINES + 1 and "1000" in str(err.value)
    with pytest.raises(DownloadError) as err:
        prepare_download([("a.dmc", "#A\nEN"), ("b.dmc", "\n#a\nEN")])
    assert "b.dmc:2:" in str(err.value) and "a.dmc:1" in str(err.value)
    with pytest.raises(DownloadError):
        prepare_lines('MG "a\\b"', "c.dmc")
    with pytest.raises(DownloadError):
        prepare_lines("MG \"caf\u00e9\"", "d.dmc")


def test_every_shipped_program_prepares(tmp_path: Path):
    files = sorted(p.name for p in PROGRAMS_DIR.glob("*.dmc"))
    assert files, "galil_programs/ holds the card's programs"
    lines = read_programs(PROGRAMS_DIR, files)
    payload = download_payload(lines)
    assert payload.endswith(b"\\") and b"REM" not in payload and b"'" not in payload
    assert all(len(pl.text) <= MAX_LINE_CHARS for pl in lines)
    with pytest.raises(DownloadError) as err:
        read_programs(tmp_path, ["missing.dmc"])
    assert "missing.dmc" in str(err.value)
    (tmp_path / "bin.dmc").write_bytes(b"#A\n\xff\n")
    with pytest.raises(DownloadError) as err:
        read_programs(tmp_path, ["bin.dmc"])
    assert err.value.line == 2


def test_download_refuses_more_labels_than_the_card_holds():
    text = "\n".join(f"#L{i}\nEN" for i in range(MAX_LABELS + 1))
    with pytest.raises(DownloadError) as err:
        prepare_download([("many.dmc", text)])
    assert err.value.code == 61 and "labels" in str(err.value)


def test_a_cards_text_reaches_logs_without_its_control_characters():
    """A program message with terminal controls (clear screen, bell) is kept as text with
    the controls escaped: it cannot clear the operator's terminal or ring through a log."""
    ev = parse_unsolicited("boom\x1b[2J\x07 done")
    assert isinstance(ev, Message) and ev.text == "boom\\x1b[2J\\x07 done"
    assert ev.text.isprintable()
    err = parse_unsolicited("?\x1b[31mJP #X")
    assert err.text.isprintable() and "\\x1b" in err.text
