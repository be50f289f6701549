"""A service that does not stop on SIGTERM says where it hangs (hydrowatch.bus.service.STOP_DUMP_S)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path


def test_a_service_that_does_not_stop_on_sigterm_writes_where_it_hangs(tmp_path: Path) -> None:
    script = tmp_path / "hang.py"
    script.write_text(
        "import argparse, time\n"
        "from hydrowatch.bus import service\n"
        "service.STOP_DUMP_S = 0.5\n"
        "def stuck_in_close(args, stop):\n"
        "    print('running', flush=True)\n"
        "    stop.wait()\n"
        "    time.sleep(60)  # a close that never returns\n"
        "service.run_service(stuck_in_close, argparse.Namespace())\n")
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "running"
    proc.send_signal(signal.SIGTERM)
    time.sleep(2.0)
    proc.kill()
    _, err = proc.communicate(timeout=10)
    assert "stuck_in_close" in err and "Thread" in err  # every thread's stack, the hanging line included
