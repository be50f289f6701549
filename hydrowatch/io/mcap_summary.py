"""What an MCAP file holds (``hydrowatch info``): channels, counts, time range, metadata, recovery."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydrowatch.errors import DataError
from hydrowatch.io.codec import decode_batch
from hydrowatch.io.mcap_io import Recovery, expected_schema, iter_records
from hydrowatch.schemas import schema_name


def summarize(path: str | Path) -> dict[str, Any]:
    """Summary of a finished or unfinished MCAP file; every message is decoded and checked.

    Returns
    -------
    dict
        ``path``, ``size_bytes``, ``finished``, ``recovery`` (one line), ``messages``,
        ``log_time_ns`` ([first, last] or None), ``duration_s``, ``metadata`` ({record: {key: value}}),
        ``channels``: list of {``topic``, ``schema``, ``message_encoding``, ``messages``,
        ``undecodable``, ``first_error``, ``samples`` and ``t_s`` ([first, last], sensor channels)}.
    """
    recovery = Recovery(str(path))
    channels: dict[str, dict[str, Any]] = {}
    first_ns: int | None = None
    last_ns: int | None = None
    for index, (channel, schema, message) in enumerate(iter_records(path, recovery)):
        info = channels.setdefault(
            channel.topic,
            {
                "topic": channel.topic,
                "schema": schema.name if schema is not None else None,
                "message_encoding": channel.message_encoding,
                "messages": 0,
                "undecodable": 0,
                "first_error": None,
            },
        )
        info["messages"] += 1
        first_ns = message.log_time if first_ns is None else min(first_ns, message.log_time)
        last_ns = message.log_time if last_ns is None else max(last_ns, message.log_time)
        expected = expected_schema(channel, schema)
        if expected is None:
            continue
        try:
            batch = decode_batch(message.data, expected, f"message {index}")
        except DataError as exc:
            info["undecodable"] += 1
            info["first_error"] = info["first_error"] or str(exc)
            continue
        if schema_name(expected) == "sensor_chunk" and batch.num_rows:
            t = batch.column("t")
            info["samples"] = info.get("samples", 0) + batch.num_rows
            t_first = info.get("t_s", [t[0].as_py(), None])[0]
            info["t_s"] = [t_first, t[batch.num_rows - 1].as_py()]
    return {
        "path": str(path),
        "size_bytes": recovery.bytes_total,
        "finished": recovery.finished,
        "recovery": recovery.describe(),
        "messages": recovery.messages,
        "log_time_ns": None if first_ns is None else [first_ns, last_ns],
        "duration_s": 0.0 if first_ns is None or last_ns is None else (last_ns - first_ns) / 1e9,
        "metadata": recovery.metadata,
        "channels": list(channels.values()),
    }


def format_summary(summary: dict[str, Any]) -> str:
    """Human-readable text of :func:`summarize`'s result."""
    lines = [
        f"file:      {summary['path']} ({summary['size_bytes']} bytes)",
        f"status:    {summary['recovery']}",
        f"messages:  {summary['messages']}",
    ]
    if summary["log_time_ns"] is not None:
        first, last = summary["log_time_ns"]
        lines.append(f"log time:  {first / 1e9:.3f} s to {last / 1e9:.3f} s ({summary['duration_s']:.3f} s)")
    lines.append("channels:")
    for c in summary["channels"]:
        text = f"  {c['topic']}  {c['schema']}  {c['message_encoding']}  {c['messages']} messages"
        if "samples" in c:
            text += f", {c['samples']} samples, t {c['t_s'][0]:.3f} s to {c['t_s'][1]:.3f} s"
        if c["undecodable"]:
            text += f", {c['undecodable']} undecodable (first: {c['first_error']})"
        lines.append(text)
    for name, data in summary["metadata"].items():
        lines.append(f"metadata {name}:")
        lines.extend(f"  {k}: {v}" for k, v in sorted(data.items()))
    return "\n".join(lines)


__all__ = ["format_summary", "summarize"]
