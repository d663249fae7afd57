"""`services.bus.serving.serve` with a reply that takes long (`Later`): the queryable's other keys keep
answering meanwhile, and the slow query gets its reply (or its error) when the work is done. A real
router process (`vrsim serve router --insecure`) and real sessions; scenario/start builds its world
this way so that status and stop answer while it builds."""

from __future__ import annotations

import subprocess
import threading
import time

from common import ScenarioError
from tests.conftest import VRSIM
from tests.integration.test_services_support import free_port, open_client


def test_a_slow_reply_does_not_hold_up_the_other_keys_of_its_queryable(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([VRSIM, "serve", "router", "--insecure", "--listen", endpoint],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=tmp_path)
    try:
        serve_slow_and_fast(endpoint, router)
    finally:
        router.terminate()
        router.wait(timeout=20)


def serve_slow_and_fast(endpoint: str, router) -> None:
    from services.bus.serving import Later, serve

    lines = [router.stderr.readline() for _ in range(2)]  # the --insecure warning, then "ready"
    assert b"ready" in lines[1], lines
    release = threading.Event()

    def slow(params, payload):
        return Later(lambda: b'"slow"' if release.wait(20) else b'"gave up"')

    def failing(params, payload):
        return Later(lambda: (_ for _ in ()).throw(ScenarioError("s.toml: [map] bad")))

    handlers = {"slow": slow, "failing": failing, "fast": lambda params, payload: b'"fast"'}
    service, client = open_client(endpoint), open_client(endpoint)
    queryable = serve(service, "t/**", handlers, "t/", "test")
    try:
        slow_replies: list = []
        asking = threading.Thread(target=lambda: slow_replies.extend(client.get("t/slow", timeout=30)))
        asking.start()
        time.sleep(0.5)  # the slow query is in its handler now
        t0 = time.monotonic()
        fast = list(client.get("t/fast", timeout=10))
        took = time.monotonic() - t0
        assert [r.ok.payload.to_bytes() for r in fast] == [b'"fast"'] and took < 2.0, took
        assert not slow_replies
        release.set()
        asking.join(timeout=30)
        assert [r.ok.payload.to_bytes() for r in slow_replies] == [b'"slow"']
        [err] = list(client.get("t/failing", timeout=10))
        assert err.ok is None and b"s.toml: [map] bad" in err.err.payload.to_bytes()
    finally:
        queryable.undeclare()
        service.close()
        client.close()
