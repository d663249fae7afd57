"""`services.bus.serving.serve` with a reply that takes long (`Later`): the queryable's other keys keep
answering meanwhile, and the slow query gets its reply (or its error) when the work is done. A real
router process (`vrsim serve router --insecure`) and real sessions; scenario/start builds its world
this way so that status and stop answer while it builds."""

from __future__ import annotations

import subprocess
import threading

from tests.conftest import VRSIM
from tests.integration.test_services_support import free_port, open_client
from vrsim.common import ScenarioError


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
    from vrsim.services.bus.serving import Later, serve

    lines = [router.stderr.readline() for _ in range(2)]  # the --insecure warning, then "ready"
    assert b"ready" in lines[1], lines
    inside, release = threading.Event(), threading.Event()

    def slow_work() -> bytes:
        inside.set()  # the slow query's work has begun: its reply is held until `release`
        return b'"slow"' if release.wait(120) else b'"gave up"'

    def slow(params, payload):
        return Later(slow_work)

    def failing(params, payload):
        return Later(lambda: (_ for _ in ()).throw(ScenarioError("s.toml: [map] bad")))

    handlers = {"slow": slow, "failing": failing, "fast": lambda params, payload: b'"fast"'}
    service, client = open_client(endpoint), open_client(endpoint)
    queryable = serve(service, "t/**", handlers, "t/", "test")
    try:
        slow_replies: list = []
        asking = threading.Thread(target=lambda: slow_replies.extend(client.get("t/slow", timeout=150)))
        asking.start()
        assert inside.wait(60), "the slow query's work never began"
        # Answered while the slow query's work is held: a queryable that waited for it would time out.
        fast = list(client.get("t/fast", timeout=60))
        assert [r.ok.payload.to_bytes() for r in fast if r.ok is not None] == [b'"fast"'], \
            f"t/fast got no reply while t/slow was held: {fast}"
        assert not slow_replies and not release.is_set()
        release.set()
        asking.join(timeout=150)
        assert [r.ok.payload.to_bytes() for r in slow_replies] == [b'"slow"']
        [err] = list(client.get("t/failing", timeout=10))
        assert err.ok is None and b"s.toml: [map] bad" in err.err.payload.to_bytes()
    finally:
        queryable.undeclare()
        service.close()
        client.close()
