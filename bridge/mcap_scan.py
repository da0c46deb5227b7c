"""A damage-tolerant walk over the records of an MCAP file, with an account of what could not be read.

The MCAP framing (opcode u8, length u64, body) is followed from the magic on. A chunk is kept only whole: its
header must be consistent (the lengths it announces add up to the record's length), it must decompress to
its announced size and match its CRC (when the writer stored one), and its records must parse; otherwise it
is *skipped* and its bytes counted as discarded. Bytes whose framing is broken (random bytes over an
opcode or a length) are stepped over to the next place where a chunk that checks out starts (resync), and
counted as discarded too. Nothing is ever guessed: a resync accepts only a chunk whose CRC matches.

A file is *closed* when it ends with a footer and the magic (its writer finished it); the summary section
is then read first, so every channel is known (even one whose record sat in a skipped chunk) and the
statistics give the exact number of messages lost. A file that ends inside a record was *cut* there (a
copy stopped short, a disk full, a kill in the middle of a write); the bytes of that last record are
discarded and counted. Messages lost in skipped chunks are counted exactly where the chunk's message index
records (written after each chunk) or the summary's statistics survive; otherwise they are estimated from
the messages per byte of the chunks that were read (``lost_exact`` False).

The caller gives a ``consumer`` with ``channel(buf, body)``, ``metadata(name, values)``,
``message(buf, pos, end)`` (a message outside any chunk) and ``chunk(data) -> (kept, orphans)`` (a chunk's
decompressed records; raises ValueError, KeyError or struct.error for records that do not parse, all or
nothing; ``orphans``: messages on a channel no readable record declares, counted as lost).
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

MCAP_MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
OP_STATISTICS, OP_METADATA, OP_DATA_END = 0x0B, 0x0C, 0x0F
_KNOWN_OPS = frozenset(range(0x01, 0x10))
_RECORD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQII")          # start time, end time, uncompressed size, crc, len(compression)
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_FOOTER_BYTES = 9 + 20                         # opcode, length, summary start u64, offsets start u64, crc u32
_MAX_CHUNK = 1 << 31                           # bytes: an announced uncompressed size above this is not a chunk


def string(buf, pos: int) -> tuple[str, int]:
    """An MCAP string (u32 length, UTF-8) at ``pos``: (text, position after it)."""
    n = _U32.unpack_from(buf, pos)[0]
    if pos + 4 + n > len(buf):
        raise ValueError("string runs past its record")
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def string_map(buf, pos: int, limit: int | None = None) -> dict[str, str]:
    """An MCAP map<string, string> at ``pos`` (ValueError if it does not end exactly where its length says,
    or runs past ``limit``)."""
    end = pos + 4 + _U32.unpack_from(buf, pos)[0]
    if limit is not None and end > limit:
        raise ValueError("map runs past its record")
    pos += 4
    out = {}
    while pos < end:
        k, pos = string(buf, pos)
        v, pos = string(buf, pos)
        out[k] = v
    if pos != end:
        raise ValueError("map entries overrun its length")
    return out


@dataclass
class Scan:
    """What the walk found and what it could not read (see the module docstring)."""
    size: int = 0                   # bytes of the file
    closed: bool = False            # footer + magic at the end: the writer finished the file
    cut: bool = False               # the file ends inside a record (or inside its summary section)
    chunks: int = 0                 # chunks read whole
    chunks_skipped: int = 0         # chunks that did not check out (CRC, compression, records), or lost to a cut
    bytes_discarded: int = 0        # bytes not read: skipped chunks, broken framing, the cut-off last record
    trailing_bytes: int = 0         # of which: the incomplete record at the end of a file that was cut
    messages: int = 0               # messages kept (in chunks read whole, plus any outside chunks)
    lost_exact: int = 0             # messages known lost: message indexes of skipped chunks, orphans
    stats_messages: int | None = None   # the summary's message count (closed file), else None
    notes: list[str] = field(default_factory=list)
    _unknown_raw: int = 0           # uncompressed bytes of skipped chunks whose message count is unknown
    _unknown_stored: int = 0        # stored bytes discarded whose content is unknown (broken framing, cut)
    _raw: int = 0                   # uncompressed bytes of the chunks read
    _stored: int = 0                # stored bytes of the chunks read

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    @property
    def messages_lost(self) -> tuple[int | None, bool]:
        """(messages lost, exact?): exact from the summary's statistics or the message indexes; an estimate
        from the messages per byte of the chunks read; None when nothing was read to estimate from."""
        if self.stats_messages is not None:
            return max(0, self.stats_messages - self.messages), True
        if not (self._unknown_raw or self._unknown_stored):
            return self.lost_exact, True
        if not self.messages or not self._raw:
            return None, False
        per_raw, per_stored = self.messages / self._raw, self.messages / max(1, self._stored)
        return self.lost_exact + round(self._unknown_raw * per_raw + self._unknown_stored * per_stored), False


def _decompress(compression: str, data, raw_size: int) -> bytes:
    if compression == "zstd":
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=raw_size)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(bytes(data))
    if compression == "":
        return bytes(data)
    raise ValueError(f"unknown chunk compression {compression!r}")


def _chunk_header(buf, pos: int, limit: int):
    """The chunk record at ``pos`` if its framing is consistent and it ends by ``limit``:
    (end, uncompressed size, crc, compression, records start, records end); else None."""
    if pos + 9 + _CHUNK_HEAD.size > limit or buf[pos] != OP_CHUNK:
        return None
    length = _U64.unpack_from(buf, pos + 1)[0]
    body = pos + 9
    end = body + length
    if end > limit:
        return None
    t0, t1, raw_size, crc, clen = _CHUNK_HEAD.unpack_from(buf, body)
    p = body + _CHUNK_HEAD.size
    if t0 > t1 or raw_size > _MAX_CHUNK or clen > 16 or p + clen + 8 > end:
        return None
    try:
        compression = bytes(buf[p:p + clen]).decode("ascii")
    except UnicodeDecodeError:
        return None
    p += clen
    nrec = _U64.unpack_from(buf, p)[0]
    if p + 8 + nrec != end:
        return None
    return end, raw_size, crc, compression, p + 8, end


def _chunk_data(buf, head) -> bytes:
    """A chunk's records, decompressed and CRC-checked; ValueError (or the codec's error) if they are not."""
    _end, raw_size, crc, compression, start, stop = head
    data = _decompress(compression, buf[start:stop], raw_size)
    if len(data) != raw_size:
        raise ValueError(f"chunk decompressed to {len(data)} bytes, {raw_size} announced")
    if crc and zlib.crc32(data) != crc:
        raise ValueError("chunk CRC mismatch")
    return data


def _metadata_at(buf, p: int, limit: int) -> bool:
    """A metadata record that parses exactly (name, map ending at its record's end) and is followed by a
    record starts at ``p``."""
    if p + 9 + 8 > limit:
        return False
    end = p + 9 + _U64.unpack_from(buf, p + 1)[0]
    if end > limit:
        return False
    try:
        _name, q = string(buf, p + 9)
        string_map(buf, q, end)
        if q + 4 + _U32.unpack_from(buf, q)[0] != end:
            return False
    except (ValueError, struct.error, UnicodeDecodeError):
        return False
    return _framed_at(buf, end, limit)


def _resync(buf, start: int, limit: int):
    """The first position at or after ``start`` where a chunk that checks out (CRC included) starts,
    (position, header, data), or a metadata record that parses exactly, (position, None, None); or None."""
    p = start
    nxt = {OP_CHUNK: -2, OP_METADATA: -2}        # the next position of each opcode byte (-1: none left)
    while p < limit:
        for op, q in nxt.items():
            if -1 < q < p or q == -2:
                nxt[op] = buf.find(bytes((op,)), p, limit)
        found = [q for q in nxt.values() if q >= 0]
        if not found:
            return None
        p = min(found)
        if buf[p] == OP_METADATA:
            if _metadata_at(buf, p, limit):
                return p, None, None
        else:
            head = _chunk_header(buf, p, limit)
            if head is not None:
                try:
                    return p, head, _chunk_data(buf, head)
                except Exception:  # noqa: BLE001  (any codec error: not a chunk after all)
                    pass
        p += 1
    return None


def _framed_at(buf, pos: int, limit: int) -> bool:
    """A record (known opcode, length within ``limit``) starts at ``pos``, or the data ends there. (A file
    cut inside the next record's first 9 bytes counts as framed: the cut is found there.)"""
    if pos >= limit or pos + 9 > limit:
        return True
    op, length = _RECORD.unpack_from(buf, pos)
    return op in _KNOWN_OPS and (pos + 9 + length <= limit or limit == len(buf))


def _footer(buf) -> int | None:
    """The summary start of a closed file (0: no summary), or None when the file does not end in a footer."""
    size = len(buf)
    fpos = size - len(MCAP_MAGIC) - _FOOTER_BYTES
    if fpos < len(MCAP_MAGIC) or bytes(buf[size - len(MCAP_MAGIC):]) != MCAP_MAGIC:
        return None
    op, length = _RECORD.unpack_from(buf, fpos)
    if op != OP_FOOTER or length != 20:
        return None
    return _U64.unpack_from(buf, fpos + 9)[0]


def _summary(buf, start: int, stop: int, scan: Scan, consumer) -> None:
    """The summary section's channels (given to the consumer) and statistics (message count), if the
    footer's CRC of the section (when the writer stored one) matches: a damaged summary is not used."""
    crc = _U32.unpack_from(buf, stop + 9 + 16)[0]
    if crc and zlib.crc32(buf[start:stop + 9 + 16]) != crc:
        scan.note("summary section damaged (CRC mismatch): not used, losses estimated")
        return
    pos = start
    try:
        while pos + 9 <= stop:
            op, length = _RECORD.unpack_from(buf, pos)
            body, end = pos + 9, pos + 9 + length
            if end > stop:
                raise ValueError("record runs past the summary")
            if op == OP_CHANNEL:
                consumer.channel(buf, body)
            elif op == OP_STATISTICS:
                scan.stats_messages = _U64.unpack_from(buf, body)[0]
            pos = end
    except (ValueError, struct.error, UnicodeDecodeError) as e:
        scan.stats_messages = None
        scan.note(f"summary section unreadable ({e}): losses estimated")


def scan(buf: bytes, consumer) -> Scan:
    """Walk ``buf`` (a whole MCAP file, magic checked by the caller) and feed ``consumer``; returns the
    account of the walk (see the module docstring)."""
    size = len(buf)
    sc = Scan(size=size)
    limit = size
    summary_start = _footer(buf)
    if summary_start is not None:
        sc.closed = True
        fpos = size - len(MCAP_MAGIC) - _FOOTER_BYTES
        if len(MCAP_MAGIC) <= summary_start <= fpos:
            limit = summary_start
            _summary(buf, summary_start, fpos, sc, consumer)
        else:
            limit = fpos
    pos = len(MCAP_MAGIC)
    pending: list | None = None            # a skipped chunk: [uncompressed bytes, messages its indexes list]

    def settle():
        nonlocal pending
        if pending is not None:
            if pending[1]:
                sc.lost_exact += pending[1]
            else:
                sc._unknown_raw += pending[0]
            pending = None

    def take_chunk(p, head, data=None) -> None:
        nonlocal pending
        end, raw_size = head[0], head[1]
        try:
            if data is None:
                data = _chunk_data(buf, head)
            kept, orphans = consumer.chunk(data)
        except Exception as e:  # noqa: BLE001  (codec, CRC, record parsing: the chunk is skipped whole)
            sc.chunks_skipped += 1
            sc.bytes_discarded += end - p
            sc.note(f"chunk at byte {p}: {type(e).__name__}: {e}"[:200])
            pending = [raw_size, 0]
            return
        sc.chunks += 1
        sc.messages += kept
        sc.lost_exact += orphans
        if orphans:
            sc.note(f"{orphans} messages on channels declared only in skipped chunks")
        sc._raw += raw_size
        sc._stored += end - p

    while pos < limit:
        if pos + 9 > limit:
            op, length = buf[pos], None
        else:
            op, length = _RECORD.unpack_from(buf, pos)
        end = pos + 9 + length if length is not None else limit + 1
        head = _chunk_header(buf, pos, limit) if op == OP_CHUNK else None
        framed = op in _KNOWN_OPS and end <= limit and (op != OP_CHUNK or head is not None)
        if framed and op != OP_CHUNK and not _framed_at(buf, end, limit):   # a length that leads nowhere
            framed = False                    # (a chunk is checked by its header and CRC instead)
        if not framed:
            found = _resync(buf, pos + 1, limit)
            if found is None:                            # nothing readable follows
                settle()
                rest = limit - pos
                sc.bytes_discarded += rest
                if op in _KNOWN_OPS and end > limit and not sc.closed:     # the file ends inside this record
                    sc.cut, sc.trailing_bytes = True, rest
                    raw = (_CHUNK_HEAD.unpack_from(buf, pos + 9)[2]
                           if op == OP_CHUNK and pos + 9 + _CHUNK_HEAD.size <= limit else None)
                    if raw is not None and raw <= _MAX_CHUNK:
                        sc._unknown_raw += raw                # the cut-off chunk's announced size
                    elif op == OP_CHUNK or length is None:
                        sc._unknown_stored += rest
                else:
                    sc._unknown_stored += rest
                    sc.note(f"{rest} unreadable bytes from byte {pos} to the end of the data")
                break
            nxt, nhead, ndata = found
            settle()
            sc.bytes_discarded += nxt - pos
            sc._unknown_stored += nxt - pos
            sc.note(f"unreadable bytes {pos}..{nxt} stepped over")
            if nhead is None:                            # a metadata record: read on as usual
                pos = nxt
                continue
            take_chunk(nxt, nhead, ndata)
            pos = nhead[0]
            continue
        body = pos + 9
        if op != OP_MESSAGE_INDEX:
            settle()
        try:
            if op == OP_CHUNK:
                take_chunk(pos, head)
            elif op == OP_MESSAGE_INDEX and pending is not None:
                pending[1] += _U32.unpack_from(buf, body + 2)[0] // 16
            elif op == OP_CHANNEL:
                consumer.channel(buf, body)
            elif op == OP_METADATA:
                name, p = string(buf, body)
                values = string_map(buf, p, end)
                consumer.metadata(name, values)
            elif op == OP_MESSAGE:
                consumer.message(buf, pos, end)
                sc.messages += 1
            elif op == OP_FOOTER:
                pos = end
                break
            elif op == OP_DATA_END and not sc.closed:      # finished, but the summary or footer is cut
                sc.cut = True
                sc.trailing_bytes = size - end
                sc.bytes_discarded += size - end
                sc.note("cut in the summary section (every chunk is before it)")
                pos = end
                break
        except (ValueError, KeyError, struct.error, UnicodeDecodeError) as e:
            sc.bytes_discarded += end - pos
            sc.note(f"record {op:#04x} at byte {pos} unreadable: {type(e).__name__}: {e}"[:200])
        pos = end
    settle()
    return sc
