"""Helpers for the security tests: `vrsim serve router` (a router enforcing `services.bus.security`) in
its own process, and sessions logged in as any user from the state folder's client configurations."""

from __future__ import annotations

import json
import os
import select
import subprocess
import time

from tests.conftest import VRSIM
from tests.integration.test_services_support import free_port

P, K = "vrsim", "vrsim/tractor1"


class SecureRouter:
    """``vrsim serve router --listen ENDPOINT --state-dir FOLDER/state [--tls]`` on a free loopback port."""

    def __init__(self, folder: str, tls: bool = False, timeout_s: float = 30.0):
        self.state = os.path.join(folder, "state")
        self.endpoint = f"{'tls' if tls else 'tcp'}/127.0.0.1:{free_port()}"
        argv = [VRSIM, "serve", "router", "--listen", self.endpoint, "--state-dir", self.state]
        self.proc = subprocess.Popen(argv + (["--tls"] if tls else []), cwd=folder, stderr=subprocess.PIPE)
        self.sessions = []
        ready, _, _ = select.select([self.proc.stderr], [], [], timeout_s)
        line = self.proc.stderr.readline() if ready else b""
        if b"ready" not in line:
            self.stop()
            raise AssertionError(f"secure router not ready within {timeout_s} s: {line!r}")

    def config_file(self, user: str) -> str:
        return os.path.join(self.state, f"{user}.json5")

    def session(self, user: str, **override):
        """A client session logged in as ``user`` (``override``: config entries to change)."""
        import zenoh

        conf = zenoh.Config.from_file(self.config_file(user))
        for path, value in override.items():
            conf.insert_json5(path.replace(".", "/"), json.dumps(value))
        session = zenoh.open(conf)
        self.sessions.append(session)
        return session

    def stop(self) -> None:
        for session in self.sessions:
            session.close()
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def plain_config(endpoint: str, **entries):
    """A client configuration with no credentials (anonymous) plus ``entries``."""
    import zenoh

    conf = zenoh.Config()
    for path, value in {"mode": "client", "connect/endpoints": [endpoint],
                        "scouting/multicast/enabled": False, **entries}.items():
        conf.insert_json5(path, json.dumps(value))
    return conf


def replies(session, selector: str, payload: bytes | None = None, timeout_s: float = 5.0) -> list:
    """The names in the stand-ins' replies to one query (denied queries: none)."""
    kwargs = {"timeout": timeout_s} | ({"payload": payload} if payload is not None else {})
    return [json.loads(r.ok.payload.to_bytes())["from"] for r in session.get(selector, **kwargs)
            if r.ok is not None]


def wait_until(predicate, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def put_until_seen(session, key: str, payload: bytes, seen, timeout_s: float = 5.0) -> bool:
    """Put ``payload`` on ``key`` until ``seen(payload)`` (a subscriber may be declared a moment late)."""
    return wait_until(lambda: (session.put(key, payload), seen(payload))[1], timeout_s)
