"""The bus: zenoh sessions, Arrow publish/subscribe on contract keys, status and shards.

See docs/bus.md for key expressions, environment variables, shards and deployment with a router.
"""

from hydrowatch.bus.keys import TOPICS, Key, key, key_expr, parse_key
from hydrowatch.bus.pubsub import Message, Publisher, Subscriber
from hydrowatch.bus.session import BusSettings, add_bus_arguments, free_port, open_session, settings_from_args
from hydrowatch.bus.shard import Shard, machine_hash, parse_shard
from hydrowatch.bus.status import StatusReporter, alive, service_id, status_batch, wait_alive

__all__ = [
    "TOPICS",
    "BusSettings",
    "Key",
    "Message",
    "Publisher",
    "Shard",
    "StatusReporter",
    "Subscriber",
    "add_bus_arguments",
    "alive",
    "free_port",
    "key",
    "key_expr",
    "machine_hash",
    "open_session",
    "parse_key",
    "parse_shard",
    "service_id",
    "settings_from_args",
    "status_batch",
    "wait_alive",
]
