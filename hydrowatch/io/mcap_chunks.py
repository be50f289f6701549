"""mcap's ``Writer`` with a fast path for already encoded messages (the recorder's hot path).

``mcap.writer.Writer`` (mcap 1.6.0, pinned in pyproject.toml) builds a record object per message
and writes every field with its own small write; closing a chunk writes the chunk and its message
index field by field and compresses with a fresh zstd context. :class:`ChunkedWriter` writes the
very same records (MCAP spec: Message 0x05, Chunk 0x06, MessageIndex 0x07; the chunk index,
statistics and summary stay mcap's; the chunk indexes are kept packed, :class:`PackedChunkIndexes`) with one
``struct.pack`` each, and compresses with one zstd
context per thread, shared by every open file: ~4 µs instead of ~7 µs per message. It reaches
into the writer's private state (name-mangled ``_Writer__…``), which is why mcap is pinned;
tests/test_bus_fastpath.py checks the bytes against mcap's own writer and reads them back with
mcap's reader.
"""

from __future__ import annotations

import struct
import threading
import zlib

import lz4.frame
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import MessageIndex
from mcap.writer import CompressionType, Writer

ZSTD_LEVEL = 1
"""zstd level of chunks: sensor chunks compress to the same ~36 % at level 1 as at mcap's default 3,
in ~35 % less time."""
_MESSAGE = struct.Struct("<BQHIQQ")
"""Message record head: opcode, record length, channel id, sequence, log time, publish time."""
_CHUNK = struct.Struct("<BQQQQII")
"""Chunk record head: opcode, record length, start time, end time, uncompressed size and CRC,
length of the compression name (then the name, the compressed length as u64 and the records)."""
_INDEX = struct.Struct("<BQHI")
"""MessageIndex record head: opcode, record length, channel id, bytes of (log time, offset) pairs."""
_U64 = struct.Struct("<Q")
_CHUNK_INDEX = struct.Struct("<BQQQQQI")
"""ChunkIndex record head: opcode, record length, message start and end time, chunk start offset and length, bytes
of the (channel id, offset) pairs."""
_PER_THREAD = threading.local()


class PackedChunkIndexes:
    """A file's chunk index records, serialised as the summary section holds them, in one growing buffer: ~90 bytes
    per chunk where mcap's ``ChunkIndex`` objects took ~680 (measured with tracemalloc). The writer keeps one record
    per chunk until the file is finished; a recorder that closes a chunk per machine every second held ~1.2 GB per
    hour of a file's life per 500 machines that way (benchmarks/bench_soak.py). Stands in the writer's list of chunk
    indexes as its only entry: the summary writes it where it wrote the objects, byte for byte the same."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.count = 0

    def add(self, start_time: int, end_time: int, chunk_start: int, chunk_length: int, offsets: dict[int, int],
            index_length: int, compression: bytes, compressed_size: int, uncompressed_size: int) -> None:
        """Append one chunk's index record (fields as mcap's ``ChunkIndex``; ``offsets``: channel id → offset of
        its MessageIndex record)."""
        pairs = b"".join(struct.pack("<HQ", channel_id, at) for channel_id, at in offsets.items())
        length = 8 * 4 + 4 + len(pairs) + 8 + 4 + len(compression) + 8 + 8
        self.data += _CHUNK_INDEX.pack(0x08, length, start_time, end_time, chunk_start, chunk_length, len(pairs))
        self.data += pairs
        self.data += struct.pack(f"<QI{len(compression)}sQQ", index_length, len(compression), compression,
                                 compressed_size, uncompressed_size)
        self.count += 1

    def write(self, builder: RecordBuilder) -> None:
        """Write every record into the summary (what ``ChunkIndex.write`` does for one)."""
        builder.write(self.data)


def _zstd() -> zstandard.ZstdCompressor:
    """This thread's compressor. One per thread, not per file: a recorder has ~1000 files open,
    and 1000 compression contexts (~1 MB each) made every chunk's compression run on cold memory
    (~280 µs instead of ~30 µs for 30 kB)."""
    compressor = getattr(_PER_THREAD, "zstd", None)
    if compressor is None:
        compressor = _PER_THREAD.zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    return compressor


class ChunkedWriter(Writer):
    """``mcap.writer.Writer`` plus :meth:`add_encoded` and a faster chunk close (same file bytes
    layout, records and indexes; chunked, with CRCs, without data-section CRC: mcap's defaults)."""

    def add_encoded(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> bool:
        """Append one message to the chunk in progress (what ``add_message`` does, statistics and
        message index included); True when it filled the chunk and the chunk was written."""
        stats, builder = self._Writer__statistics, self._Writer__chunk_builder  # type: ignore[attr-defined]
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        if builder.num_messages == 0 or log_time < builder.message_start_time:
            builder.message_start_time = log_time
        if log_time > builder.message_end_time:
            builder.message_end_time = log_time
        index = builder.message_indices.get(channel_id)
        if index is None:
            index = builder.message_indices[channel_id] = MessageIndex(channel_id=channel_id, records=[])
        buffer = builder.record_writer._buffer
        index.records.append((log_time, buffer.tell()))
        buffer.write(_MESSAGE.pack(0x05, 22 + len(data), channel_id, sequence, log_time, publish_time))
        buffer.write(data)
        builder.num_messages += 1
        if buffer.tell() > self._Writer__chunk_size:  # type: ignore[attr-defined]
            self._Writer__finalize_chunk()  # type: ignore[attr-defined]
            return True
        return False

    def _Writer__finalize_chunk(self) -> None:  # noqa: N802 - overrides Writer.__finalize_chunk
        builder = self._Writer__chunk_builder  # type: ignore[attr-defined]
        if builder is None or builder.num_messages == 0:
            return
        self._Writer__statistics.chunk_count += 1  # type: ignore[attr-defined]
        records = builder.end()
        kind = self._Writer__compression  # type: ignore[attr-defined]
        if kind == CompressionType.ZSTD:
            compression, packed = b"zstd", _zstd().compress(records)
        elif kind == CompressionType.LZ4:
            compression, packed = b"lz4", lz4.frame.compress(records)
        else:
            compression, packed = b"", records
        self._Writer__flush()  # type: ignore[attr-defined]
        stream = self._Writer__stream  # type: ignore[attr-defined]
        start = stream.tell()
        length = 8 * 3 + 4 + 4 + len(compression) + 8 + len(packed)
        start_time, end_time = builder.message_start_time, builder.message_end_time
        stream.write(b"".join((
            _CHUNK.pack(0x06, length, start_time, end_time, len(records), zlib.crc32(records), len(compression)),
            compression, _U64.pack(len(packed)), packed,
        )))
        index_start = start + 9 + length
        offsets, parts, at = {}, [], index_start
        for channel_id, index in builder.message_indices.items():
            pairs = [value for entry in index.records for value in entry]
            parts.append(_INDEX.pack(0x07, 6 + 8 * len(pairs), channel_id, 8 * len(pairs)))
            parts.append(struct.pack(f"<{len(pairs)}Q", *pairs))
            offsets[channel_id] = at
            at += 15 + 8 * len(pairs)
        stream.write(b"".join(parts))
        indexes = self._Writer__chunk_indices  # type: ignore[attr-defined]
        if not indexes:
            indexes.append(PackedChunkIndexes())
        indexes[0].add(start_time, end_time, start, 9 + length, offsets, at - index_start, compression, len(packed),
                       len(records))
        builder.reset()


__all__ = ["ZSTD_LEVEL", "ChunkedWriter", "PackedChunkIndexes"]
