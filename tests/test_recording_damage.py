"""Damaged recordings are reported as such (issue: "honest recordings").

Files are damaged the ways a bench damages them: 64 random bytes every few KB (a bad disk or copy), cut in
half (a copy stopped short), killed before the writer closed the file (no summary or footer: the file ends
at a chunk boundary, as a SIGKILLed recorder leaves it, simulated by a writer never finished), garbage, empty,
a header only. The reader (bridge.mcap_recorder.read_recording / read_topics) must keep exactly the
messages of the chunks that check out and count what it could not read against the truth the test knows
(the clean file); `rtsim resim`, `rtsim play` and `rtsim view` must say so on their first line and in
their JSON, and a file with nothing usable must be an error: one line, exit 2.

How a session ended is read from the ``rtsim.session_end`` metadata record a recorder writes at a clean
close (``how``: "stopped", "model_fault" with ``reason_code``, ``reason``, ``message``, ``step``,
``sim_time``, ``coordinate``); without it, a closed file is "closed, end not recorded" (an older rtsim) and
an unclosed one "not closed (killed or crashed)" with the last recorded status's ``run_state`` and
``model_fault``. The test files carry those records exactly as specified, written with the mcap writer.
"""
from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bridge.mcap_recorder import SESSION_END_METADATA, Recorder, read_recording, read_topics
from rtsim.channels import SENSOR_NAMES
from rtsim.errors import ConfigError, RtsimError

ROOT = Path(__file__).resolve().parents[1]
VID = "car3"
FAULT = {"reason_code": "3", "reason": "non_finite_force", "message": "non-finite generalized force on 'rack'",
         "step": "2525", "sim_time": "2.525", "coordinate": "rack"}
FAULT_TEXT = ("non_finite_force (code 3): non-finite generalized force on 'rack' at step 2525, t = 2.525 s, "
              "coordinate rack")


# ----------------------------------------------------------------------------------------------- files
def _small_recording(path: Path, n: int = 6000, status=None) -> int:
    """A recording of ``n`` sensor samples (500 Hz) and a status every 50 samples (``status``: extra
    fields of the last one), small chunks; returns the number of messages written."""
    rnd = random.Random(7)
    with Recorder(path, VID, chunk_size=16 * 1024, metadata={"rtsim.session": {"vehicle_id": VID}}) as rec:
        for i in range(n):
            rec.record("sensors", i * 2_000_000, {c: rnd.uniform(-1, 1) for c in SENSOR_NAMES})
            if i % 50 == 0 or i == n - 1:
                last = i == n - 1
                rec.record("status", i * 2_000_000, {"mode": "realtime", "run_state": "running", "steps": i,
                                                     **((status or {}) if last else {})})
    return rec.written


def _rewrite(src: Path, dst: Path, *, chunk_size: int = 16 * 1024, close: bool = True,
             session_end: dict | None = None, last_status: dict | None = None) -> int:
    """``src`` written again with the mcap writer: every schema, channel, message and metadata record (but
    its rtsim.session_end, which only this function's ``session_end`` sets), in small chunks; ``last_status`` (fields) added to a copy of the last status message, appended; then
    ``session_end`` as the rtsim.session_end record and a clean finish (``close``), or no finish at all: the
    file ends after its last complete chunk, as a writer killed between two chunks leaves it. Returns the
    messages written."""
    with open(src, "rb") as fh:
        reader = make_reader(fh)
        meta = [(m.name, dict(m.metadata)) for m in reader.iter_metadata() if m.name != SESSION_END_METADATA]
        msgs = list(reader.iter_messages(log_time_order=False))
    out = open(dst, "wb")
    w = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
    w.start(profile="", library="rtsim-test")
    for name, values in meta:
        w.add_metadata(name, values)
    schemas, channels = {}, {}
    last = None
    for schema, channel, m in msgs:
        if schema is not None and schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                      schemas.get(channel.schema_id, 0))
        w.add_message(channels[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
        if channel.topic.endswith("/status"):
            last = (channels[channel.id], m)
    n = len(msgs)
    if last_status is not None:
        cid, m = last
        w.add_message(cid, m.log_time + 1_000_000, json.dumps({**json.loads(m.data), **last_status}).encode(),
                      m.log_time + 1_000_000, m.sequence + 1)
        n += 1
    if close:
        if session_end is not None:
            w.add_metadata(SESSION_END_METADATA, session_end)
        w.finish()
    else:
        w.flush()
    out.close()
    return n


def _sprinkle(data: bytes, every: int, seed: int = 1, first: int | None = None) -> bytes:
    """64 random bytes every ``every`` bytes (from ``first``, default ``every``) of the data section (up to
    the summary of a closed file)."""
    from bridge.mcap_scan import _footer

    rnd = random.Random(seed)
    b = bytearray(data)
    end = _footer(data) or len(b)
    for off in range(every if first is None else first, end - 64, every):
        b[off:off + 64] = rnd.randbytes(64)
    return bytes(b)


def _every_chunk_damaged(data: bytes) -> bytes:
    """``data`` with 64 random bytes in the middle of each chunk's compressed records."""
    from bridge.mcap_scan import _chunk_header

    rnd = random.Random(3)
    b = bytearray(data)
    p = 8
    while (p := data.find(b"\x06", p)) >= 0:
        head = _chunk_header(data, p, len(data))
        if head is not None:
            mid = (head[4] + head[5]) // 2
            b[mid:mid + 64] = rnd.randbytes(64)
            p = head[0]
        else:
            p += 1
    return bytes(b)


def _same_messages(got: dict, want: dict) -> int:
    """Every message ``got`` holds is the clean file's message of the same topic and sequence; returns how
    many there are."""
    n = 0
    for topic, msgs in got.items():
        by_seq = {m.sequence: m for m in want[topic]}
        for m in msgs:
            assert by_seq[m.sequence] == m, (topic, m.sequence)
        n += len(msgs)
    return n


# ------------------------------------------------------------------------------------------ the reader
def test_an_intact_file_reads_whole_and_says_so(tmp_path):
    path = tmp_path / "ok.mcap"
    n = _small_recording(path)
    got, info = read_recording(path)
    assert info.complete and not info.damaged and info.usable
    assert info.messages == n and info.messages_lost == 0 and info.bytes_discarded == 0 and info.chunks_skipped == 0
    assert info.session_end == {"how": "closed, end not recorded", "recorded": False}   # an rtsim before the record
    assert info.health_line().startswith("recording intact, closed")
    # the independent reference: the mcap library's reader gives the same messages
    with open(path, "rb") as fh:
        ref = [(c.topic, m.sequence, json.loads(m.data))
               for _s, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    assert [(t, m.sequence, m.data) for t, ms in got.items() for m in ms] == \
        sorted(ref, key=lambda r: [t for t in got].index(r[0]))


@pytest.mark.parametrize("closed", [True, False])
def test_random_bytes_every_few_kb_lose_only_their_chunks_and_are_counted(tmp_path, closed):
    clean = tmp_path / "clean.mcap"
    n = _small_recording(clean)
    want, _ = read_recording(clean)
    src = tmp_path / "src.mcap"
    _rewrite(clean, src, close=closed)
    data = src.read_bytes()
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_sprinkle(data, 40_000))
    got, info = read_recording(bad)
    kept = _same_messages(got, want)                    # nothing made up, nothing altered
    hits = len(range(40_000, len(data) - 64, 40_000))
    assert len(range(40_000, len(data) // 2, 40_000)) >= 4
    assert info.complete == closed and info.damaged and info.usable
    assert 0 < info.chunks_skipped <= hits and info.bytes_discarded >= 64 * info.chunks_skipped
    assert kept == info.messages and 0 < kept < n
    truth = n - kept
    if closed:                                          # the summary's statistics: exact
        assert info.messages_lost_exact and info.messages_lost == truth
    elif info.messages_lost_exact:                      # the skipped chunks' message indexes survived
        assert info.messages_lost == truth
    else:                                               # estimated from the chunks read: same order
        assert 0.5 * truth <= info.messages_lost <= 1.5 * truth
    line = info.health_line()
    assert line.startswith("DAMAGED recording: ") and f"{info.chunks_skipped} unreadable chunk" in line
    assert ("not closed" in line) != closed
    # the fast reader of the page reads the same
    tg, ti = read_topics(bad, [f"rtsim/{VID}/sensors"])
    assert [json.loads(b) for b in tg[f"rtsim/{VID}/sensors"].data] == [m.data for m in got[f"rtsim/{VID}/sensors"]]
    assert ti.damage == info.damage


def test_a_damaged_summary_is_not_trusted(tmp_path):
    """Bytes over the summary section's statistics: its CRC (in the footer) fails, the summary is not used
    (no made-up count of messages): every message is still read from the chunks, the topics too."""
    from bridge.mcap_scan import _footer

    path = tmp_path / "ok.mcap"
    n = _small_recording(path)
    want, _ = read_recording(path)
    data = bytearray(path.read_bytes())
    start = _footer(bytes(data))
    stats = start                                       # the statistics record of the summary
    while data[stats] != 0x0B:
        stats += 9 + int.from_bytes(data[stats + 1:stats + 9], "little")
    data[stats + 9:stats + 17] = (10 ** 9).to_bytes(8, "little")      # its message count
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    got, info = read_recording(bad)
    assert _same_messages(got, want) == n == info.messages and set(got) == set(want)
    assert info.complete and info.messages_lost == 0 and "summary section damaged" in info.note


def test_random_bytes_over_the_framing_are_stepped_over(tmp_path):
    """Bytes over a record's opcode and length (no length to follow): the walk resyncs on the next chunk
    that checks out, and keeps every later chunk."""
    clean = tmp_path / "clean.mcap"
    n = _small_recording(clean)
    want, _ = read_recording(clean)
    data = clean.read_bytes()
    from bridge.mcap_scan import _chunk_header
    starts = [p for p in range(8, len(data)) if data[p] == 6 and _chunk_header(data, p, len(data)) is not None]
    assert len(starts) > 10
    b = bytearray(data)
    for p in starts[2:8:2]:                             # three chunks' opcode and length overwritten
        b[p:p + 9] = b"\xff" * 9
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(b))
    got, info = read_recording(bad)
    kept = _same_messages(got, want)
    assert info.chunks == len(starts) - 3 and info.bytes_discarded > 0
    assert info.messages_lost_exact and info.messages_lost == n - kept > 0


def test_a_file_cut_in_half_says_it_was_cut(tmp_path):
    path = tmp_path / "full.mcap"
    n = _small_recording(path)
    want, _ = read_recording(path)
    data = path.read_bytes()
    half = tmp_path / "half.mcap"
    half.write_bytes(data[:len(data) // 2])
    got, info = read_recording(half)
    kept = _same_messages(got, want)
    assert info.cut and not info.complete and info.truncated_bytes > 0 and info.usable
    assert info.bytes_discarded == info.truncated_bytes
    assert not info.messages_lost_exact and info.messages_lost > 0 and kept + info.messages_lost < n
    line = info.health_line()
    assert line.startswith("DAMAGED recording: ") and "cut off mid-record" in line and "not closed" in line


def test_a_killed_writer_leaves_an_unclosed_file_whose_end_is_the_last_status(tmp_path):
    clean = tmp_path / "clean.mcap"
    _small_recording(clean)
    killed = tmp_path / "killed.mcap"
    n = _rewrite(clean, killed, close=False, last_status={"run_state": "model_fault", "model_fault": FAULT})
    got, info = read_recording(killed)
    assert not info.complete and not info.cut and info.messages == n and info.messages_lost == 0
    end = info.session_end
    assert end["how"] == "not closed (killed or crashed)" and not end["recorded"]
    assert end["last_run_state"] == "model_fault" and end["model_fault"] == FAULT
    line = info.health_line()
    assert line.startswith("UNCLOSED recording: not closed")
    assert line.endswith("session ended: not closed (killed or crashed), last status model_fault: " + FAULT_TEXT)
    # the standard reader cannot read it through its summary; this one reads every message
    with open(killed, "rb") as fh, pytest.raises(Exception):
        list(make_reader(fh).iter_messages())


@pytest.mark.parametrize("how", ["stopped", "model_fault"])
def test_the_recorded_end_of_a_closed_session(tmp_path, how):
    clean = tmp_path / "clean.mcap"
    _small_recording(clean)
    path = tmp_path / f"{how}.mcap"
    _rewrite(clean, path, session_end={"how": how, **(FAULT if how == "model_fault" else {})})
    _, info = read_recording(path)
    assert not info.damaged and SESSION_END_METADATA in info.metadata
    end = info.session_end
    assert end["how"] == how and end["recorded"]
    assert end.get("model_fault") == (FAULT if how == "model_fault" else None)
    line = info.health_line()
    assert line.startswith("recording intact, closed")
    assert line.endswith("session ended: stopped" if how == "stopped" else "session ended: model fault: " + FAULT_TEXT)


def test_garbage_empty_and_header_only(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(random.Random(2).randbytes(5000))
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    for f in (garbage, empty):
        with pytest.raises(ConfigError, match=f.name):
            read_recording(f)
        with pytest.raises(ConfigError, match=f.name):
            read_topics(f, [])
    full = tmp_path / "full.mcap"
    _small_recording(full)
    head = tmp_path / "head.mcap"
    head.write_bytes(full.read_bytes()[:60])            # magic and part of the header record
    for cut in (8, 60):
        head.write_bytes(full.read_bytes()[:cut])
        got, info = read_recording(head)
        assert not info.usable and info.messages == 0 and not info.complete
        assert info.damaged and "not closed" in info.health_line()
        assert info.cut == (cut == 60)


# -------------------------------------------------------------------------- the commands, on a session
@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 3 s session of the assembled service (fast mode, no ECU: no received frames; loopback hub, no
    Zenoh), written again in 16 KiB chunks so that damage every few KB hits several of them."""
    from bridge.can_bus import LoopbackHub
    from rtsim.service.server import ServeOptions, Service
    from waits import HUB_START

    d = tmp_path_factory.mktemp("session")
    raw = d / "raw.mcap"
    hub = LoopbackHub(0, start_timeout=HUB_START)
    svc = None
    try:
        svc = Service(ServeOptions(scenario=ROOT / "configs/scenarios/step_steer_80kph.toml", mode="fast",
                                   can_interface="remote", can_channel=hub.channel, start_hub=False,
                                   zenoh=False, record=raw), out=lambda *a: None)
        assert svc.pacer.run(steps=3000) == 3000
    finally:
        if svc is not None:
            svc.close()
        hub.close()
    path = d / "session.mcap"
    n = _rewrite(raw, path)
    return path, n


def _cli(capsys, *argv):
    from rtsim.cli import main

    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _damaged(session, tmp_path):
    path, n = session
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_sprinkle(path.read_bytes(), 30_000))
    return bad, n


def test_resim_of_an_intact_session(session, capsys):
    path, _ = session
    rc, out, _ = _cli(capsys, "resim", path)
    lines = out.splitlines()
    assert rc == 0 and lines[0] == f"rtsim resim: {path}: " + read_recording(path)[1].health_line()
    assert "recording intact, closed" in lines[0] and "session ended: closed, end not recorded" in lines[0]
    assert lines[-1] == "rtsim resim: IDENTICAL"


def test_resim_of_random_bytes_every_30_kb(session, tmp_path, capsys):
    bad, n = _damaged(session, tmp_path)
    rc, out, _ = _cli(capsys, "resim", bad)
    first = out.splitlines()[0]
    assert rc == 0 and first.startswith(f"rtsim resim: {bad}: DAMAGED recording: ") and "unreadable chunk" in first
    assert out.splitlines()[-1].endswith("(over what the damaged recording holds)")
    rc, out, _ = _cli(capsys, "resim", bad, "--json")
    rep = json.loads(out)
    dmg = rep["damage"]
    assert rc == 0 and dmg["damaged"] and dmg["closed"] and not dmg["cut"] and dmg["chunks_skipped"] > 0
    assert dmg["messages_lost_exact"] and dmg["messages_lost"] == n - dmg["messages_read"] > 0
    assert dmg["bytes_discarded"] > 0 and dmg["session_end"]["how"] == "closed, end not recorded"
    assert rep["health"].startswith("DAMAGED recording: ")
    # what was read re-simulates identically: nothing damaged is taken for a difference of the model
    assert rep["sensors"]["matched"] > 0 and rep["sensors"]["max_abs_diff"] == {}


def test_resim_of_the_first_half_says_it_was_cut(session, tmp_path, capsys):
    path, _ = session
    data = path.read_bytes()
    half = tmp_path / "half.mcap"
    half.write_bytes(data[:len(data) // 2])
    rc, out, _ = _cli(capsys, "resim", half)
    lines = out.splitlines()
    assert rc == 0 and "cut off mid-record" in lines[0] and "not closed" in lines[0], out
    assert lines[-1] == "rtsim resim: IDENTICAL (over what the damaged recording holds)", out
    rc, out, _ = _cli(capsys, "resim", half, "--json")
    rep = json.loads(out)
    assert rep["identical"] and rep["damage"]["cut"] and not rep["damage"]["closed"]
    rc, _, _ = _cli(capsys, "resim", half, "--strict")      # identical, but not over the whole session
    assert rc == 1
    rc, _, _ = _cli(capsys, "resim", session[0], "--strict")
    assert rc == 0


def test_resim_of_a_killed_session_that_ended_in_a_model_fault(session, tmp_path, capsys):
    path, n = session
    killed = tmp_path / "killed.mcap"
    _rewrite(path, killed, close=False, last_status={"run_state": "model_fault", "model_fault": FAULT})
    rc, out, _ = _cli(capsys, "resim", killed, "--json")
    rep = json.loads(out)
    end = rep["damage"]["session_end"]
    assert rc == 0 and not rep["damage"]["closed"] and not rep["damage"]["cut"]
    assert end["how"] == "not closed (killed or crashed)" and end["last_run_state"] == "model_fault"
    assert end["model_fault"] == FAULT
    rc, out, _ = _cli(capsys, "resim", killed)
    first = out.splitlines()[0]
    assert "UNCLOSED recording: not closed" in first and "last status model_fault" in first


def test_resim_of_a_closed_session_with_its_recorded_end(session, tmp_path, capsys):
    path, _ = session
    ended = tmp_path / "ended.mcap"
    _rewrite(path, ended, session_end={"how": "model_fault", **FAULT})
    rc, out, _ = _cli(capsys, "resim", ended, "--json")
    rep = json.loads(out)
    assert rc == 0 and not rep["damage"]["damaged"]
    assert rep["damage"]["session_end"] == {"how": "model_fault", "recorded": True, "model_fault": FAULT}


@pytest.mark.parametrize("kind", ["garbage", "empty", "header", "no_chunk"])
def test_nothing_usable_is_one_line_and_exit_2(session, tmp_path, capsys, kind):
    path, _ = session
    data = path.read_bytes()
    f = tmp_path / f"{kind}.mcap"
    f.write_bytes({"garbage": random.Random(5).randbytes(20_000), "empty": b"", "header": data[:40],
                   # every chunk damaged: the metadata is there, nothing to re-run or compare
                   "no_chunk": _every_chunk_damaged(data)}[kind])
    for cmd in (["resim", f], ["play", f, "--can-interface", "virtual", "--can-channel", "rec-damage"],
                ["view", f, "--port", "0", "--duration", "0.1"]):
        rc, out, err = _cli(capsys, *cmd)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert rc == 2 and len(lines) == 1 and lines[0].startswith("rtsim: error: ") and str(f) in lines[0], \
            (cmd, rc, out, err)
        assert "Traceback" not in err
        if kind in ("header", "no_chunk"):
            assert "not closed" in lines[0] or "unreadable chunk" in lines[0], lines[0]


def test_play_reports_damage_first_and_in_json(session, tmp_path, capsys):
    bad, _ = _damaged(session, tmp_path)
    rc, out, _ = _cli(capsys, "play", bad, "--can-interface", "virtual", "--can-channel", "rec-damage-play",
                      "--rate", "50")
    first = out.splitlines()[0]
    assert rc == 0 and first.startswith(f"rtsim play: {bad}: DAMAGED recording: ") and "unreadable chunk" in first
    rc, out, _ = _cli(capsys, "play", bad, "--can-interface", "virtual", "--can-channel", "rec-damage-play",
                      "--rate", "50", "--json")
    rep = json.loads(out)
    assert rc == 0 and rep["recording"]["chunks_skipped"] > 0 and rep["recording"]["damaged"]
    assert rep["stats"]["sent"] == rep["frames"] > 0 and rep["stats"]["ended"] == "done"


def test_view_reports_damage_first_and_in_the_pages_message(session, tmp_path, capsys):
    from rtsim.viewer.recording import Recording

    bad, _ = _damaged(session, tmp_path)
    rec = Recording(bad)
    assert rec.damage["damaged"] and rec.damage["chunks_skipped"] > 0 and rec.health.startswith("DAMAGED")
    msg = json.loads(rec.payload(0))
    assert msg["damage"] == json.loads(json.dumps(rec.damage)) and msg["health"] == rec.health
    intact = Recording(session[0])
    assert not intact.damage["damaged"] and json.loads(intact.payload(0))["damage"]["closed"]
    rc, out, _ = _cli(capsys, "view", bad, "--port", "0", "--duration", "0.2")
    assert rc == 0 and out.splitlines()[0] == f"rtsim view: {bad}: {rec.health}"
    header = tmp_path / "header.mcap"
    header.write_bytes(session[0].read_bytes()[:40])
    with pytest.raises(RtsimError, match="not closed"):
        Recording(header)


def test_any_damage_reads_a_subset_and_never_raises(tmp_path):
    """Random damage (bytes at random places, of random lengths, a random cut, or both) on 40 copies:
    the reader never raises, keeps only messages of the clean file, accounts for the rest (read + lost
    = written where the count is exact), and the page's fast reader agrees with it."""
    clean = tmp_path / "clean.mcap"
    n = _small_recording(clean, n=2000)
    want, _ = read_recording(clean)
    data = clean.read_bytes()
    rnd = random.Random(11)
    bad = tmp_path / "bad.mcap"
    for case in range(40):
        b = bytearray(data)
        for _ in range(rnd.randrange(0, 6)):
            off, k = rnd.randrange(8, len(b)), rnd.choice((1, 9, 64, 700))
            b[off:off + k] = rnd.randbytes(min(k, len(b) - off))
        if rnd.random() < 0.5:
            b = b[:rnd.randrange(9, len(b))]
        bad.write_bytes(bytes(b))
        got, info = read_recording(bad)
        kept = _same_messages(got, want)
        assert kept == info.messages, case
        lost = info.messages_lost
        if info.complete and info.messages_lost_exact:
            assert kept + lost == n, case
        elif lost is not None:
            assert kept + lost <= n or not info.messages_lost_exact, case
        if not info.damaged:          # damage the reader does not see (in a message index) lost nothing
            assert kept == n and info.complete, case
        tg, ti = read_topics(bad, [f"rtsim/{VID}/status"])
        assert ti.damage == info.damage, case
