"""`make dev`: the Dagster UI on 127.0.0.1, stopped cleanly by Ctrl-C (SIGINT) or SIGTERM.

A shell that starts a job in the background hands it SIGINT as *ignored*, and `dagster dev` keeps that
disposition, so it would never stop on Ctrl-C. The child therefore gets default handlers back, and this
wrapper forwards SIGINT/SIGTERM to it and waits for it to shut its webserver and daemon down.
"""

import os
import signal
import subprocess
import sys


def main() -> int:
    host = os.environ.get("TRAFFICLEARN_UI_HOST", "127.0.0.1")
    port = os.environ.get("TRAFFICLEARN_UI_PORT", "3000")
    cmd = [sys.executable, "-m", "dagster", "dev", "-m", "pipelines.definitions", "-h", host, "-p", port]

    def restore_defaults() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)

    child = subprocess.Popen(cmd, preexec_fn=restore_defaults)
    print(f"Dagster UI on http://{host}:{port} (Ctrl-C stops it)", flush=True)

    def forward(signum, _frame) -> None:
        if child.poll() is None:
            child.send_signal(signal.SIGINT)  # dagster dev shuts down cleanly on SIGINT

    signal.signal(signal.SIGINT, forward)
    signal.signal(signal.SIGTERM, forward)
    try:
        return child.wait()
    finally:
        if child.poll() is None:
            child.kill()


if __name__ == "__main__":
    sys.exit(main())
