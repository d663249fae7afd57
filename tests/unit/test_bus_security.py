"""The security state folder and the ACL document (the router's enforcement: tests/integration)."""

from __future__ import annotations

import os
import stat

import pytest

from vrsim.common import ServiceError
from vrsim.services.bus import security
from vrsim.services.bus.config import Keys


def mode(path: str) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def test_prepare_state_writes_private_files_and_keeps_passwords(tmp_path):
    folder = str(tmp_path / "state")
    first = security.prepare_state(folder)
    assert mode(folder) == 0o700 and mode(first.dictionary_file) == 0o600
    assert set(first.passwords) == set(security.USERS)
    assert len(set(first.passwords.values())) == len(security.USERS)
    assert all(len(p) >= 32 and ":" not in p for p in first.passwords.values())
    again = security.prepare_state(folder)
    assert again.passwords == first.passwords
    assert security.load_state(folder).passwords == first.passwords
    rotated = security.prepare_state(folder, rotate=True)
    assert not set(rotated.passwords.values()) & set(first.passwords.values())
    assert "password" not in repr(rotated) and first.passwords["operator"] not in repr(rotated)


def test_a_folder_others_can_enter_or_a_symlinked_file_is_refused(tmp_path):
    folder = tmp_path / "open"
    folder.mkdir(mode=0o755)
    os.chmod(folder, 0o755)
    with pytest.raises(ServiceError, match="mode 0755 lets others in"):
        security.prepare_state(str(folder))
    private = tmp_path / "private"
    security.prepare_state(str(private))
    os.chmod(private / security.DICTIONARY, 0o644)
    with pytest.raises(ServiceError, match="mode 0644"):
        security.load_state(str(private))
    os.unlink(private / security.DICTIONARY)
    elsewhere = tmp_path / "elsewhere.txt"
    elsewhere.write_text("operator:stolen\n")
    os.chmod(elsewhere, 0o600)
    os.symlink(elsewhere, private / security.DICTIONARY)
    with pytest.raises(ServiceError, match="symlink"):
        security.load_state(str(private))
    link = tmp_path / "link"
    os.symlink(private, link)
    with pytest.raises(ServiceError, match="not a folder"):
        security.load_state(str(link))


def test_load_state_names_what_is_missing_and_never_echoes_a_password(tmp_path):
    with pytest.raises(ServiceError, match="does not exist.*--insecure"):
        security.load_state(str(tmp_path / "none"))
    folder = tmp_path / "state"
    state = security.prepare_state(str(folder))
    security._write_private(state.dictionary_file, b"operator:secret-value\nbroken-line-secret\n")
    with pytest.raises(ServiceError, match="line 2 is not user:password") as err:
        security.load_state(str(folder))
    assert "secret" not in str(err.value).replace(str(folder), "")
    with pytest.raises(ServiceError, match="no user 'nobody'"):
        security.SecurityState(str(folder), {"operator": "x"}).password("nobody")


def test_acl_gives_each_user_its_own_subject_and_denies_by_default():
    acl = security._acl_config(Keys("vrsim", "tractor1"))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert [s["usernames"] for s in acl["subjects"]] == [[u] for u in security.USER_ROLES]
    rules = {r["id"]: r for r in acl["rules"]}
    viewer = [rules[i] for p in acl["policies"] if p["subjects"] == ["viewer"] for i in p["rules"]]
    asked = {k for r in viewer if "query" in r["messages"] for k in r["key_exprs"]}
    assert asked == set(security._read_only_keys(Keys()))
    assert not any("put" in r["messages"] and "ingress" in r["flows"] for r in viewer)
    vehicle_puts = {k for p in acl["policies"] if p["subjects"] == ["vehicle"] for i in p["rules"]
                    for k in rules[i]["key_exprs"] if "put" in rules[i]["messages"]}
    assert vehicle_puts == {"vrsim/tractor1/pose"}
    with pytest.raises(ServiceError, match="unknown role 'root'"):
        security._acl_config(Keys(), {"eve": "root"})


def test_the_web_user_gets_exactly_what_its_page_shows():
    k = Keys("vrsim", "tractor1")
    acl = security._acl_config(k)
    rules = {r["id"]: r for r in acl["rules"]}
    web = [rules[i] for p in acl["policies"] if p["subjects"] == ["web"] for i in p["rules"]]

    def keys(message, flow):
        return {e for r in web if message in r["messages"] and flow in r["flows"] for e in r["key_exprs"]}

    assert keys("query", "ingress") == set(security._web_keys(k)) == {
        "vrsim/map/info", "vrsim/map/rate", "vrsim/tractor1/report", "vrsim/tractor1/monitor/status",
        "vrsim/tractor1/monitor/run", "vrsim/tractor1/monitor/records", "vrsim/scenario/status"}
    assert keys("declare_subscriber", "ingress") == {"vrsim/tractor1/pose", "vrsim/tractor1/shaft",
                                                     "vrsim/tractor1/rate"}
    assert keys("liveliness_token", "ingress") == {"vrsim/alive/web"}
    assert not keys("put", "ingress") and not keys("declare_queryable", "ingress")
    assert {k.monitor_run, k.monitor_records} <= set(security._read_only_keys(k))


def test_router_and_client_settings_with_tls(tmp_path):
    from cryptography import x509

    state = security.prepare_state(str(tmp_path / "s"), tls=True)
    assert all(mode(state.tls_file(n)) == 0o600 for n in security.TLS_FILES)
    with open(state.tls_file("router.pem"), "rb") as fh:
        cert = x509.load_pem_x509_certificate(fh.read())
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in names.get_values_for_type(x509.DNSName)
    assert [str(a) for a in names.get_values_for_type(x509.IPAddress)] == ["127.0.0.1", "::1"]
    with pytest.raises(ServiceError, match="TLS is on"):
        security.router_settings(state, Keys(), ["tcp/127.0.0.1:7448"])
    router = security.router_settings(state, Keys(), ["tls/127.0.0.1:7448"])
    assert router["transport/link/tls/listen_private_key"] == state.tls_file("router-key.pem")
    client = security._client_settings(state, "viewer", ["tls/127.0.0.1:7448"])
    assert client["transport/link/tls/root_ca_certificate"] == state.tls_file("ca.pem")
    assert client["transport/auth/usrpwd/password"] == state.passwords["viewer"]
    doc = security._settings_document(client)
    assert doc["transport"]["auth"]["usrpwd"]["user"] == "viewer" and doc["mode"] == "client"


def test_settings_apply_to_a_zenoh_config(tmp_path):
    import zenoh

    state = security.prepare_state(str(tmp_path / "s"))
    settings = security.router_settings(state, Keys(), ["tcp/127.0.0.1:1"])
    conf = security.apply_settings(zenoh.Config(), settings)
    assert '"default_permission":"deny"' in conf.get_json("access_control")
    paths = security.write_client_configs(state, ["tcp/127.0.0.1:1"], users=("operator",))
    loaded = zenoh.Config.from_file(paths["operator"])
    assert loaded.get_json("transport/auth/usrpwd/user") == '"operator"'
    assert mode(paths["operator"]) == 0o600


def test_the_state_folder_never_shows_as_untracked_in_a_git_checkout(tmp_path):
    import shutil
    import subprocess

    git = shutil.which("git")
    if git is None:
        pytest.skip("git is not installed")
    subprocess.run([git, "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "field.geojson").write_text("{}")
    state = security.prepare_state(str(tmp_path / security.DEFAULT_STATE_DIR), tls=True)
    shown = subprocess.run([git, "status", "--porcelain", "--untracked-files=all"], cwd=tmp_path,
                           capture_output=True, text=True, check=True).stdout
    assert shown == "?? field.geojson\n"  # the user's own file shows; nothing of the state folder does
    ignore = os.path.join(state.folder, security.GITIGNORE)
    assert mode(ignore) == 0o600 and open(ignore, "rb").read() == security.GITIGNORE_TEXT
    os.unlink(ignore)  # a folder made before vrsim wrote one gets it on the next start
    security.prepare_state(state.folder)
    assert os.path.exists(ignore)
    assert security.load_state(state.folder).passwords == state.passwords
