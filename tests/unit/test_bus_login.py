"""How `ZenohOptions` turns into a zenoh configuration: a secure router, a client logged in from the state
folder, a complete client file used as it is, an open bus on purpose, and what `serve all` hands its
children. (The router enforcing it, between real processes: tests/integration/test_secure_serve_all.py.)"""

from __future__ import annotations

import json

import pytest

from vrsim.common import ServiceError
from vrsim.services.bus import security
from vrsim.services.bus.config import DEFAULT_ENDPOINT, ZenohOptions


def entry(conf, path: str):
    return json.loads(conf.get_json(path))


def test_a_router_enforces_the_model_and_writes_every_users_configuration(tmp_path):
    state = str(tmp_path / "state")
    conf = ZenohOptions(listen=("tcp/0.0.0.0:17001",), state_dir=state).config("router")
    assert entry(conf, "mode") == "router"
    assert entry(conf, "access_control/default_permission") == "deny"
    assert entry(conf, "transport/auth/usrpwd/dictionary_file") == f"{state}/dictionary.txt"
    assert entry(conf, "transport/link/rx/max_message_size") == security.MAX_BODY_BYTES + 1024 * 1024
    viewer = json.loads((tmp_path / "state" / "viewer.json5").read_text())
    assert viewer["connect"]["endpoints"] == ["tcp/127.0.0.1:17001"]  # the any-address made loopback
    assert viewer["transport"]["auth"]["usrpwd"]["user"] == "viewer"


def test_a_client_logs_in_from_the_state_folder_and_finds_the_router(tmp_path):
    state = str(tmp_path / "state")
    ZenohOptions(listen=("tcp/127.0.0.1:17002",), state_dir=state).config("router")
    passwords = security.load_state(state).passwords
    conf = ZenohOptions(state_dir=state).config("client")  # vrsim query: operator by default
    assert entry(conf, "connect/endpoints") == ["tcp/127.0.0.1:17002"]
    assert entry(conf, "transport/auth/usrpwd/user") == "operator"
    assert entry(conf, "transport/auth/usrpwd/password") == passwords["operator"]
    web = ZenohOptions(user="web", state_dir=state).config("client", default_user="map")
    assert entry(web, "transport/auth/usrpwd/user") == "web"
    service = ZenohOptions(connect=("tcp/127.0.0.1:9",), state_dir=state).config("client", default_user="map")
    assert entry(service, "transport/auth/usrpwd/user") == "map"
    assert entry(service, "connect/endpoints") == ["tcp/127.0.0.1:9"]  # --connect wins


def test_a_client_file_that_logs_in_is_used_as_it_is_and_one_that_does_not_gets_credentials(tmp_path):
    state = str(tmp_path / "state")
    ZenohOptions(listen=("tcp/127.0.0.1:17003",), state_dir=state).config("router")
    viewer_file = str(tmp_path / "state" / "viewer.json5")
    conf = ZenohOptions(config_file=viewer_file, state_dir=str(tmp_path / "absent")).config("client")
    assert entry(conf, "transport/auth/usrpwd/user") == "viewer"
    plain = tmp_path / "plain.json5"
    plain.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:17003"] } }')
    conf = ZenohOptions(config_file=str(plain), state_dir=state, user="viewer").config("client")
    assert entry(conf, "transport/auth/usrpwd/user") == "viewer"
    assert entry(conf, "connect/endpoints") == ["tcp/127.0.0.1:17003"]


def test_no_state_folder_is_a_clear_error_and_insecure_needs_none(tmp_path):
    with pytest.raises(ServiceError, match=r"state folder .*absent: does not exist; start `vrsim serve all`"):
        ZenohOptions(state_dir=str(tmp_path / "absent")).config("client")
    conf = ZenohOptions(state_dir=str(tmp_path / "absent"), insecure=True).config("client")
    assert entry(conf, "connect/endpoints") == [DEFAULT_ENDPOINT]
    assert entry(conf, "transport/auth/usrpwd/user") is None
    router = ZenohOptions(insecure=True, state_dir=str(tmp_path / "absent")).config("router")
    assert entry(router, "access_control/enabled") is False
    assert not (tmp_path / "absent").exists()


def test_tls_listens_on_tls_and_clients_trust_the_private_ca(tmp_path):
    state = str(tmp_path / "state")
    conf = ZenohOptions(tls=True, state_dir=state).config("router")
    assert entry(conf, "listen/endpoints") == [DEFAULT_ENDPOINT.replace("tcp/", "tls/")]
    assert entry(conf, "transport/link/tls/listen_certificate") == f"{state}/tls/router.pem"
    client = ZenohOptions(state_dir=state).config("client")
    assert entry(client, "connect/endpoints") == [DEFAULT_ENDPOINT.replace("tcp/", "tls/")]
    assert entry(client, "transport/link/tls/root_ca_certificate") == f"{state}/tls/ca.pem"
    with pytest.raises(ServiceError, match="TLS is on, so every endpoint must be tls/"):
        ZenohOptions(tls=True, listen=("tcp/127.0.0.1:17004",), state_dir=state).config("router")


def test_children_of_serve_all_get_the_state_folder_their_user_and_the_zenoh_config(tmp_path):
    conf = tmp_path / "z.json5"
    secure = ZenohOptions(listen=("tcp/0.0.0.0:17005",), config_file=str(conf), state_dir="st")
    args = secure.child_args("monitor")
    assert args[:2] == ["--connect", "tcp/127.0.0.1:17005"]
    assert args[args.index("--zenoh-config") + 1] == str(conf)
    assert args[args.index("--user") + 1] == "monitor"
    assert args[args.index("--state-dir") + 1].endswith("/st")
    insecure = ZenohOptions(insecure=True).child_args("map")
    assert "--insecure" in insecure and "--user" not in insecure and "--state-dir" not in insecure
