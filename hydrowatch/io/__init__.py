"""File formats and message encoding: Arrow codec, MCAP, Parquet and CSV.

``read_recording`` / ``write_recording`` pick the format by suffix (.mcap, .parquet, .csv);
``encode_batch`` / ``decode_batch`` are the bus and MCAP message codec; ``McapWriter``,
``iter_messages`` and ``summarize`` work on MCAP files, finished or not; ``hydrowatch.io.foxglove``
re-encodes them as JSON that Foxglove plots. See docs/formats.md.
"""

from hydrowatch.io.codec import (
    SchemaMismatchError,
    SchemaVersionError,
    UndecodableMessageError,
    arrays_from_sensor_chunk,
    decode_batch,
    encode_batch,
    sensor_chunk_from_arrays,
)
from hydrowatch.io.mcap_io import McapWriter, Recovery, iter_messages, topic
from hydrowatch.io.mcap_summary import format_summary, summarize
from hydrowatch.io.recordings import read_recording, write_recording

__all__ = [
    "McapWriter",
    "Recovery",
    "SchemaMismatchError",
    "SchemaVersionError",
    "UndecodableMessageError",
    "arrays_from_sensor_chunk",
    "decode_batch",
    "encode_batch",
    "format_summary",
    "iter_messages",
    "read_recording",
    "sensor_chunk_from_arrays",
    "summarize",
    "topic",
    "write_recording",
]
