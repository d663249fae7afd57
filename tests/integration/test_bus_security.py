"""The bus's security model with real zenoh sessions: a router enforcing `services.bus.security` in its
own process, and client sessions on 127.0.0.1 logged in as each user. Stand-ins logged in as the
services declare exactly the keys the real services declare and record every query and sample that
reaches them, so a denied query is one the service never saw, not merely one whose reply was lost.

Clients of a zenoh router send a put only when they know of a matching subscriber, and the router
tells only publishers about subscribers; so the forged puts that prove the router's own filter come
from a service that publishes elsewhere (the controller forging poses), not from a viewer.
"""

from __future__ import annotations

import json

import pytest

from tests.integration.secure_bus import K, P, SecureRouter, plain_config, put_until_seen, replies

CONTROL_KEYS = (f"{P}/scenario/start", f"{P}/scenario/stop", f"{P}/map/load", f"{K}/control/load",
                f"{K}/control/step", f"{K}/monitor/load", f"{K}/vehicle/start", f"{K}/vehicle/stop")
READ_ONLY_KEYS = (f"{P}/map/info", f"{P}/map/rate", f"{K}/report", f"{K}/monitor/status",
                  f"{K}/vehicle/status", f"{P}/scenario/status")
STREAMS = ("pose", "shaft", "rate")


def answer_as(name: str):
    """A queryable callback replying ``{"from": name}``."""
    return lambda query: query.reply(query.key_expr, json.dumps({"from": name}).encode())


class StandIns:
    """Sessions logged in as map, vehicle, controller, monitor and scenario, serving their keys."""

    def __init__(self, router: SecureRouter):
        self.queries: list[tuple[str, str]] = []  # (service, key) of every query that reached one
        self.samples: list[tuple[str, bytes]] = []  # (key, payload) the monitor received
        self.keep = []
        serves = {"map": [f"{P}/map/**"], "vehicle": [f"{K}/vehicle/**"], "controller": [f"{K}/control/**"],
                  "monitor": [f"{K}/*", f"{K}/monitor/**"], "scenario": [f"{P}/scenario/**", f"{P}/*"]}
        self.sessions = {name: router.session(name) for name in serves}
        for name, keys in serves.items():
            for key in keys:
                self.keep.append(self.sessions[name].declare_queryable(key, self._on_query(name)))
        for stream in STREAMS:
            self.keep.append(self.sessions["monitor"].declare_subscriber(
                f"{K}/{stream}", lambda s: self.samples.append((str(s.key_expr), s.payload.to_bytes()))))

    def _on_query(self, name: str):
        answer = answer_as(name)

        def on_query(query):
            self.queries.append((name, str(query.key_expr)))
            answer(query)
        return on_query

    def reached(self, key: str) -> bool:
        return any(k == key for _, k in self.queries)

    def received(self, payload: bytes) -> bool:
        return any(p == payload for _, p in self.samples)


@pytest.fixture(scope="module")
def bus(tmp_path_factory):
    router = SecureRouter(str(tmp_path_factory.mktemp("secure")))
    try:
        router.standins = StandIns(router)
        yield router
    finally:
        router.stop()


def test_anonymous_unknown_user_and_wrong_password_cannot_connect(bus):
    import zenoh

    cases = {"anonymous": plain_config(bus.endpoint),
             "unknown user": plain_config(bus.endpoint, **{"transport/auth/usrpwd/user": "mallory",
                                                          "transport/auth/usrpwd/password": "x" * 32}),
             "wrong password": plain_config(bus.endpoint, **{"transport/auth/usrpwd/user": "operator",
                                                            "transport/auth/usrpwd/password": "x" * 32})}
    for case, conf in cases.items():
        with pytest.raises(zenoh.ZError):
            zenoh.open(conf).close()
            pytest.fail(f"{case}: connected")


def test_state_folder_is_private(bus):
    import os
    import stat

    for root, _dirs, files in os.walk(bus.state):
        assert stat.S_IMODE(os.stat(root).st_mode) == 0o700, root
        for name in files:
            assert stat.S_IMODE(os.stat(os.path.join(root, name)).st_mode) == 0o600, name


def test_viewer_reads_but_changes_nothing(bus):
    s = bus.standins
    viewer = bus.session("viewer")
    for key in READ_ONLY_KEYS:
        assert len(replies(viewer, key)) == 1, key
    for key in CONTROL_KEYS:
        assert replies(viewer, key, payload=b"{}") == [], key
        assert not s.reached(key), f"{key} reached its service"
    for wide in (f"{P}/**", f"{K}/**", f"{P}/scenario/*"):  # wider than the read-only keys: refused whole
        assert replies(viewer, wide) == [], wide
    # subscribe: yes, to everything published
    got = []
    sub = viewer.declare_subscriber(f"{P}/**", lambda sample: got.append(sample.payload.to_bytes()))
    try:
        assert put_until_seen(s.sessions["vehicle"], f"{K}/pose", b"v-pose", got.__contains__)
    finally:
        sub.undeclare()


def test_viewer_cannot_impersonate_a_service(bus):
    s = bus.standins
    viewer, operator = bus.session("viewer"), bus.session("operator")
    fake_queryable = viewer.declare_queryable(f"{P}/map/rate", answer_as("fake"))
    fake_token = viewer.liveliness().declare_token(f"{P}/alive/controller")
    try:
        for stream in STREAMS:
            viewer.put(f"{K}/{stream}", b"viewer-forged")
        assert replies(operator, f"{P}/map/rate") == ["map"]
        alive = [str(r.ok.key_expr) for r in operator.liveliness().get(f"{P}/alive/*", timeout=2) if r.ok]
        assert alive == [f"{P}/alive/router"]
        assert put_until_seen(s.sessions["vehicle"], f"{K}/pose", b"marker-1", s.received)
        assert not s.received(b"viewer-forged")
    finally:
        fake_queryable.undeclare()
        fake_token.undeclare()


def test_each_service_puts_only_on_its_own_keys(bus):
    s = bus.standins
    seen = []  # an operator's view of the bus (the monitor's own puts reach its own subscriber locally)
    observer = bus.session("operator").declare_subscriber(f"{P}/**",
                                                          lambda x: seen.append(x.payload.to_bytes()))
    owner = {"pose": "vehicle", "shaft": "controller", "rate": "controller"}
    try:
        for stream in STREAMS:
            for name in ("map", "vehicle", "controller", "monitor", "scenario"):
                if name != owner[stream]:
                    s.sessions[name].put(f"{K}/{stream}", f"forged-{name}-{stream}".encode())
        for stream in STREAMS:
            mark = f"real-{stream}".encode()
            assert put_until_seen(s.sessions[owner[stream]], f"{K}/{stream}", mark,
                                  lambda m: s.received(m) and m in seen), stream
    finally:
        observer.undeclare()
    assert [p for p in seen if p.startswith(b"forged")] == []
    assert [p for _, p in s.samples if p.startswith(b"forged") and b"monitor" not in p] == []


def test_each_service_asks_only_what_it_needs(bus):
    s = bus.standins
    refused = {"controller": f"{P}/scenario/start", "monitor": f"{K}/vehicle/stop",
               "map": f"{K}/control/load", "vehicle": f"{P}/map/load", "scenario": f"{K}/control/step"}
    for name, key in refused.items():
        assert replies(s.sessions[name], key, payload=b"{}") == [], (name, key)
        assert not s.reached(key), f"{name} reached {key}"
    allowed = {"vehicle": f"{K}/control/step", "scenario": f"{K}/vehicle/start"}
    for name, key in allowed.items():
        assert len(replies(s.sessions[name], key, payload=b"{}")) == 1, (name, key)
    # a service serving someone else's keys is not heard: only the controller answers control/step
    fake = s.sessions["map"].declare_queryable(f"{K}/control/**", answer_as("map pretending"))
    try:
        assert replies(s.sessions["vehicle"], f"{K}/control/step", payload=b"[]") == ["controller"]
    finally:
        fake.undeclare()


def test_the_router_drops_bodies_over_the_cap_before_any_service_sees_them(bus):
    from vrsim.services.bus.security import MAX_BODY_BYTES

    s = bus.standins
    operator = bus.session("operator")
    assert replies(operator, f"{P}/map/rate", payload=b" " * 1000) == ["map"]
    before = len(s.queries)
    assert replies(operator, f"{P}/map/rate", payload=b" " * (MAX_BODY_BYTES + 1)) == []
    assert len(s.queries) == before


def test_a_wildcard_query_reaches_no_service_even_for_the_operator(bus):
    """zenoh checks the query's own key against each service's rules on the way out: `vrsim/**` is
    wider than any service's keys (a limitation of the ACL noted in docs/security.md)."""
    s = bus.standins
    before = len(s.queries)
    assert replies(bus.session("operator"), f"{P}/**") == []
    assert len(s.queries) == before


def test_operator_starts_stops_and_queries_everything_but_publishes_nothing(bus):
    s = bus.standins
    operator = bus.session("operator")
    expected = {f"{P}/scenario/start": "scenario", f"{P}/scenario/stop": "scenario", f"{P}/map/load": "map",
                f"{K}/control/load": "controller", f"{K}/control/step": "controller",
                f"{K}/monitor/load": "monitor", f"{K}/vehicle/start": "vehicle",
                f"{K}/vehicle/stop": "vehicle", f"{K}/report": "monitor", f"{P}/scenario/status": "scenario",
                f"{P}/map/rate": "map"}
    for key, service in expected.items():
        assert replies(operator, key, payload=b"{}") == [service], key
    operator.put(f"{K}/shaft", b"operator-forged")
    assert put_until_seen(s.sessions["controller"], f"{K}/shaft", b"marker-2", s.received)
    assert not s.received(b"operator-forged")


@pytest.fixture(scope="module")
def tls_bus(tmp_path_factory):
    router = SecureRouter(str(tmp_path_factory.mktemp("secure-tls")), tls=True)
    try:
        yield router
    finally:
        router.stop()


def test_tls_clients_log_in_and_plain_or_untrusting_ones_cannot(tls_bus):
    import zenoh

    map_session = tls_bus.session("map")
    queryable = map_session.declare_queryable(f"{P}/map/**", answer_as("map"))
    try:
        assert replies(tls_bus.session("viewer"), f"{P}/map/info") == ["map"]
        assert replies(tls_bus.session("viewer"), f"{P}/map/load") == []
        with open(tls_bus.config_file("operator")) as fh:
            auth = json.load(fh)["transport"]["auth"]["usrpwd"]
        credentials = {"transport/auth/usrpwd/user": auth["user"],
                       "transport/auth/usrpwd/password": auth["password"]}
        plain_tcp = plain_config(tls_bus.endpoint.replace("tls/", "tcp/"), **credentials)
        no_ca = plain_config(tls_bus.endpoint, **credentials)  # the system's CAs do not know vrsim's
        for conf in (plain_tcp, no_ca):
            with pytest.raises(zenoh.ZError):
                zenoh.open(conf).close()
    finally:
        queryable.undeclare()
