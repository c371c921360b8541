"""`make dev`: the Dagster UI comes up on 127.0.0.1 and Ctrl-C (SIGINT) stops it and its children cleanly."""

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dev_server_starts_and_stops_on_sigint(isolated_home):
    port = _free_port()
    dagster_home = isolated_home / "dagster"
    dagster_home.mkdir(parents=True)
    (dagster_home / "dagster.yaml").write_text((REPO / "dagster.yaml").read_text())
    env = {**os.environ, "DAGSTER_HOME": str(dagster_home), "TRAFFICLEARN_UI_PORT": str(port)}
    # started the way a background job of a script is: with SIGINT ignored
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipelines.dev"], cwd=REPO, env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN), start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 120
        up = False
        while time.time() < deadline and proc.poll() is None:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/server_info", timeout=2) as r:
                    up = r.status == 200
                    break
            except OSError:
                time.sleep(1)
        assert up, "Dagster UI did not come up on 127.0.0.1"
        os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C in a terminal: the whole foreground group
        assert proc.wait(timeout=60) == 0  # `make dev` then ends without "make: *** Error 1"
        # the webserver, daemon and code server go too: nothing of the process group is left behind
        deadline = time.time() + 30
        while time.time() < deadline:
            alive = subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True, text=True).stdout.split()
            if not alive:
                break
            time.sleep(0.5)
        assert alive == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def test_dev_server_refuses_a_busy_port(isolated_home):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        env = {**os.environ, "TRAFFICLEARN_UI_PORT": str(busy.getsockname()[1])}
        proc = subprocess.run([sys.executable, "-m", "pipelines.dev"], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stderr.startswith("error:") and "already in use" in proc.stderr and len(proc.stderr.splitlines()) == 1


def test_unusable_host_or_port_is_one_line_and_ipv6_is_probed():
    from pipelines.dev import _unusable

    assert "cannot serve on nohost.invalid:3000" in _unusable("nohost.invalid", "3000")
    assert "cannot serve on 127.0.0.1:abc" in _unusable("127.0.0.1", "abc")
    assert "ports are 1-65535" in _unusable("127.0.0.1", "70000")
    if socket.has_ipv6:
        with socket.socket(socket.AF_INET6) as busy:
            try:
                busy.bind(("::1", 0))
            except OSError:  # no IPv6 loopback on this machine
                return
            busy.listen()
            assert "already in use" in _unusable("::1", str(busy.getsockname()[1]))
