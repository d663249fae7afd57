"""The monitor's database is its owner's alone (0600 in a 0700 folder); a router that would listen in
plain text beyond this machine says so on stderr at start."""

import os
import sqlite3
import stat

import pytest

from vrsim.common import ServiceError
from vrsim.services.bus.config import ZenohOptions, _plain_beyond_loopback
from vrsim.services.bus.monitor import DEFAULT_DB_FOLDER, MonitorStore, _default_db


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_a_new_database_is_0600_in_a_new_0700_folder(tmp_path):
    path = tmp_path / "new" / "m.sqlite"
    store = MonitorStore(str(path))
    store.db.execute("INSERT INTO meta VALUES ('probe', 'x')")  # the WAL file exists now
    assert _mode(path.parent) == 0o700
    assert _mode(path) == 0o600
    assert _mode(str(path) + "-wal") == 0o600
    store.db.close()


def test_an_older_world_readable_database_is_tightened(tmp_path):
    path = tmp_path / "m.sqlite"
    sqlite3.connect(path).close()
    os.chmod(path, 0o644)
    MonitorStore(str(path)).db.close()
    assert _mode(path) == 0o600


def test_the_default_database_is_in_a_folder_of_its_own_made_0700(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    os.makedirs(DEFAULT_DB_FOLDER, mode=0o755)
    os.chmod(DEFAULT_DB_FOLDER, 0o755)
    path = _default_db(ZenohOptions())
    assert os.path.dirname(path) == DEFAULT_DB_FOLDER
    MonitorStore(path).db.close()
    assert _mode(DEFAULT_DB_FOLDER) == 0o700 and _mode(path) == 0o600


def test_a_database_named_through_a_symlink_is_refused(tmp_path):
    (tmp_path / "elsewhere.sqlite").write_bytes(b"")
    os.symlink(tmp_path / "elsewhere.sqlite", tmp_path / "m.sqlite")
    with pytest.raises(ServiceError, match="m.sqlite: is a symlink"):
        MonitorStore(str(tmp_path / "m.sqlite"))


def test_plain_endpoints_beyond_loopback_are_found():
    endpoints = ["tcp/127.0.0.1:7448", "tcp/[::1]:7448", "tcp/localhost:7448", "tls/0.0.0.0:7448",
                 "quic/0.0.0.0:7448", "tcp/0.0.0.0:7448", "tcp/[::]:7448", "tcp/192.168.1.20:7448",
                 "udp/10.0.0.1:7448", "tcp/farm-pc:7448", "tcp/127.0.0.2:7448#iface=lo"]
    assert _plain_beyond_loopback(endpoints) == ["tcp/0.0.0.0:7448", "tcp/[::]:7448", "tcp/192.168.1.20:7448",
                                                "udp/10.0.0.1:7448", "tcp/farm-pc:7448"]


@pytest.mark.parametrize("listen, warned", [(("tcp/0.0.0.0:7448",), True), (("tcp/127.0.0.1:7448",), False)])
def test_a_router_warns_at_start_when_it_listens_in_plain_text_beyond_loopback(listen, warned, capsys):
    ZenohOptions(listen=listen, insecure=True).config("router")
    lines = capsys.readouterr().err.splitlines()
    assert lines == ([f"vrsim serve: warning: the router listens on {listen[0]} in plain text beyond this "
                      "machine: passwords and every message cross the network unencrypted (use --tls, or a "
                      "loopback address)"] if warned else [])


def test_a_client_connecting_beyond_loopback_is_not_warned(capsys):
    ZenohOptions(connect=("tcp/192.168.1.20:7448",), insecure=True).config("client")
    assert capsys.readouterr().err == ""
