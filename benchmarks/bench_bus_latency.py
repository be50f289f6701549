"""Latency publish -> receive on the bus at 100 machines (200 Hz, 0.1 s chunks, real time).

The plant service runs as its own process; this process subscribes like any service and takes,
for every message, receive time minus the publish time the publisher attached (both wall-clock,
same host). The first ``--warmup`` seconds are left out: the plant's first chunks come late while
it loads its compiled kernel and it then catches up in one burst (start-up, not steady state; the
figure including them is printed too). Reference: p99 < 10 ms.

Usage: python benchmarks/bench_bus_latency.py [--machines 100] [--seconds 10] [--warmup 2] [--express]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

import numpy as np

from hydrowatch.bus import BusSettings, Subscriber, free_port, open_session
from hydrowatch.bus.service import SWITCH_INTERVAL_S

REFERENCE_P99_MS = 10.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=100)
    parser.add_argument("--seconds", type=float, default=10.0, help="wall-clock seconds to measure")
    parser.add_argument("--warmup", type=float, default=2.0, help="seconds left out at the start (default 2)")
    parser.add_argument("--express", action="store_true", help="plant sends every message at once (no batching)")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    sys.setswitchinterval(SWITCH_INTERVAL_S)  # as every service does
    port = free_port()
    latencies: list[int] = []
    with open_session(BusSettings(port=port)) as session, Subscriber(session, "hydro/lat/*/sensors") as sub:
        plant = subprocess.Popen([
            sys.executable, "-m", "services.plant", "--fleet", "lat", "--machines", str(args.machines), "--speed", "1",
            "--wait-subscribers", "60", "--bus-port", str(port), *(["--express"] if args.express else [])])
        try:
            first = sub.recv(timeout=120)
            assert first is not None, "no message from the plant"
            start = time.monotonic()
            warmup: list[int] = [first.receive_time_ns - first.publish_time_ns]
            while (now := time.monotonic()) < start + args.warmup + args.seconds:
                message = sub.recv(timeout=1.0)
                if message is not None:
                    (latencies if now >= start + args.warmup else warmup).append(
                        message.receive_time_ns - message.publish_time_ns)
        finally:
            plant.send_signal(signal.SIGTERM)
            plant.wait(timeout=60)
    ms = np.asarray(latencies) / 1e6
    p50, p99, worst = np.percentile(ms, [50, 99, 100])
    rate = len(ms) / args.seconds
    print(f"machines={args.machines} express={args.express} messages={len(ms)} "
          f"({rate:.0f} msgs/s, {rate * 20:.0f} samples/s) after {args.warmup:g} s warm-up")
    print(f"latency p50={p50:.2f} ms  p99={p99:.2f} ms  max={worst:.2f} ms")
    p99_all = np.percentile(np.concatenate([warmup, latencies]) / 1e6, 99)
    print(f"  with the warm-up ({len(warmup)} messages): p99={p99_all:.2f} ms")
    print(f"p99 ratio to reference {REFERENCE_P99_MS:g} ms: {p99 / REFERENCE_P99_MS:.2f} (below 1 meets it)")
    print(f"load average before {load_before:.1f}, after {os.getloadavg()[0]:.1f} "
          "(a shared 2-core machine: figures are pessimistic)")


if __name__ == "__main__":
    main()
