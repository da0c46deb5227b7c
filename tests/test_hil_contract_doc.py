"""What docs/hil-contract.md tells an ECU developer is what the simulator accepts: for every command
message of every shipped DBC, a frame built by hand from the page's recipe (the value by the DBC's
scaling, an alive counter in byte 6 bits 0-3, byte 7 a CRC-8 SAE J1850 written here from its definition:
polynomial 0x1D, init 0xFF, final xor 0xFF, over the message's E2EDataID byte then bytes 0-6) is accepted,
at the message's GenMsgCycleTime, and the same frame with a wrong CRC or a repeated counter is not."""
from __future__ import annotations

from pathlib import Path

import cantools
import pytest

from bridge.can_codec import Codec, CommandReceiver
from rtsim.channels import car_channels, two_wheeler_channels

ROOT = Path(__file__).resolve().parents[1]
CHANNELS = {"xbw": lambda: car_channels(), "xbw_fwd": lambda: car_channels(("fl", "fr")),
            "eps_car": lambda: car_channels(("fl", "fr"), eps=True), "motorcycle": two_wheeler_channels}


def crc8_sae_j1850(data: bytes) -> int:
    """Bitwise, from the definition (not the codec's table)."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def test_the_crc_is_the_catalogue_one():
    assert crc8_sae_j1850(b"123456789") == 0x4B


def command_messages(db):
    return [m for m in db.messages if any(s.name.endswith("_counter") for s in m.signals)
            and any(s.name.endswith("_crc") for s in m.signals) and m.name != "SIM_STEP_REQ" and "ECU" in m.senders]


def by_hand(msg, value: float, counter: int) -> bytes:
    """The page's recipe: value by the DBC's scaling, counter in byte 6 bits 0-3, CRC in byte 7."""
    sig = next(s for s in msg.signals if not s.name.endswith(("_counter", "_crc")))
    body = bytearray(msg.encode({s.name: 0 for s in msg.signals} | {sig.name: value}, strict=False))
    body[6] = (body[6] & 0xF0) | (counter & 0x0F)
    data_id = msg.dbc.attributes["E2EDataID"].value
    body[7] = crc8_sae_j1850(bytes((data_id,)) + bytes(body[:7]))
    return bytes(body)


@pytest.mark.parametrize("name", sorted(CHANNELS))
def test_frames_built_from_the_page_are_accepted(name):
    path = ROOT / "configs" / "can" / f"{name}.dbc"
    db = cantools.database.load_file(str(path))
    codec = Codec(path, CHANNELS[name]())
    messages = command_messages(db)
    assert messages, f"{name}.dbc has no E2E-protected command"
    for msg in messages:
        sig = next(s for s in msg.signals if not s.name.endswith(("_counter", "_crc")))
        value = 0.5 * ((sig.minimum or 0.0) + (sig.maximum or 0.0))
        period = msg.cycle_time / 1000.0
        rx = CommandReceiver(codec)
        for k in range(20):                                   # past a wrap of the counter
            assert rx.receive(msg.frame_id, by_hand(msg, value, k % 16), (k + 1) * period), (msg.name, k)
        t = 21 * period
        assert not rx.receive(msg.frame_id, by_hand(msg, value, 19 % 16), t), "a repeated counter is refused"
        bad = bytearray(by_hand(msg, value, 20 % 16))
        bad[7] ^= 0x01
        assert not rx.receive(msg.frame_id, bytes(bad), t + period), "a wrong CRC is refused"
        assert rx.counters["crc"] >= 1
