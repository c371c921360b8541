"""`make dev`: the Dagster UI on 127.0.0.1, stopped cleanly by Ctrl-C (SIGINT) or SIGTERM.

A shell that starts a job in the background hands it SIGINT as *ignored*, and `dagster dev` keeps that
disposition, so it would never stop on Ctrl-C. The child therefore gets default handlers back, and this
wrapper forwards SIGINT/SIGTERM to it and waits for it to shut its webserver and daemon down.
"""

import os
import signal
import socket
import subprocess
import sys

from pipelines.instance import InstanceError, dagster_home
from warehouse.storage import home


def _unusable(host: str, port: str) -> str | None:
    """Why the UI cannot serve on host:port, or None. A busy port matters most: dagster dev would log "Serving ..."
    and keep its daemon running with no webserver."""
    try:
        if not 1 <= int(port) <= 65535:
            raise ValueError("ports are 1-65535")
        addresses = socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM)  # IPv4 and IPv6 alike
    except (socket.gaierror, ValueError) as e:
        return f"cannot serve on {host}:{port} ({e}); set TRAFFICLEARN_UI_HOST / TRAFFICLEARN_UI_PORT"
    for family, kind, proto, _, address in addresses:
        with socket.socket(family, kind, proto) as probe:
            probe.settimeout(1.0)
            if probe.connect_ex(address) == 0:
                return f"{host}:{port} is already in use (another `make dev`?); set TRAFFICLEARN_UI_PORT to use another port"
    return None


def main() -> int:
    host = os.environ.get("TRAFFICLEARN_UI_HOST", "127.0.0.1")
    port = os.environ.get("TRAFFICLEARN_UI_PORT", "3000")
    problem = _unusable(host, port)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 1
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cmd = [sys.executable, "-m", "dagster", "dev", "-m", "pipelines.definitions", "-d", repo, "-h", host, "-p", port]
    # run from DAGSTER_HOME: from the checkout, dagster dev warns that the template dagster.yaml there "will not be used";
    # the homes as absolute paths, so that a relative one still means what it meant here
    try:
        cwd = str(dagster_home())
    except InstanceError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    homes = {"DAGSTER_HOME": cwd, "TRAFFICLEARN_HOME": str(home())}

    def restore_defaults() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)

    # `dagster dev` still works; its notice that the `dg` CLI (not installed) supersedes it only confuses
    quiet = ",".join(filter(None, [os.environ.get("PYTHONWARNINGS"), "ignore:Function `dev_command` is superseded"]))
    env = {**os.environ, **homes, "PYTHONWARNINGS": quiet}
    child = subprocess.Popen(cmd, preexec_fn=restore_defaults, cwd=cwd, env=env)
    print(f"Dagster UI on http://{host}:{port} (Ctrl-C stops it)", flush=True)

    stopped = False

    def forward(signum, _frame) -> None:
        nonlocal stopped
        stopped = True
        if child.poll() is None:
            child.send_signal(signal.SIGINT)  # dagster dev shuts down cleanly on SIGINT

    signal.signal(signal.SIGINT, forward)
    signal.signal(signal.SIGTERM, forward)
    try:
        code = child.wait()
        # Ctrl-C reaches dagster dev twice (terminal + forward): it exits 1 "Aborted!", yet the stop is the user's
        return 0 if stopped else code
    finally:
        if child.poll() is None:
            child.kill()


if __name__ == "__main__":
    sys.exit(main())
