"""Who may do what on the vrsim bus: Zenoh user/password authentication, access control, TLS.

Everything is Zenoh's own machinery: the router holds a user/password dictionary
(``transport/auth/usrpwd/dictionary_file``) so a session without a known user and the right password
is refused during the handshake, and ``access_control`` rules whose subjects are those usernames say
which messages each user may send and receive on which key expressions (default: deny). TLS on the
links is an option (``tls/`` endpoints, a private CA generated into the state folder).

The state folder (``.vrsim/`` beside where ``vrsim serve`` runs unless told otherwise) is private:
the folder 0700, every file 0600, owned by the user running vrsim; a folder that others can read or
that someone else owns is refused. It holds

- ``dictionary.txt``: ``user:password`` lines, the router's dictionary;
- ``<user>.json5``: a complete client configuration per user (mode, endpoint, credentials, CA), so a
  plain zenoh program logs in with ``zenoh.Config.from_file(".vrsim/viewer.json5")``;
- ``tls/``: ``ca.pem``, ``router.pem``, ``router-key.pem`` when TLS is on;
- ``.gitignore``: ``*``, so that the folder never shows in a git checkout it lies in (as pytest's
  cache does); written when missing.

Users: one per service (`SERVICE_USERS`) and two people roles, ``operator`` (start and stop runs,
query every key, subscribe to everything) and ``viewer`` (query the read-only keys and subscribe;
nothing that changes state). What each user may do is its role's list of `_Grant`; `ROLES` is the
registry, `USER_ROLES` maps a user to its role (``web`` is a viewer narrowed to what its page shows:
`_web_keys`, the three streams and its liveliness token; its start and stop log in as ``operator``).

How the ACL is evaluated (zenoh 1.x, ``zenoh/src/net/routing/interceptor/authorization.rs``): the
router checks each message against the rules of the session it enters from (ingress) or leaves
through (egress); a rule applies when one of its key expressions *includes* the message's key
expression, so a subscription or query on a wildcard wider than the granted keys is denied as a whole.
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from vrsim.common import ServiceError
from vrsim.services.bus.config import Keys

DEFAULT_STATE_DIR = ".vrsim"
SERVICE_USERS = ("vehicle", "controller", "monitor", "map", "scenario", "web")
PEOPLE_USERS = ("operator", "viewer")
USERS = SERVICE_USERS + PEOPLE_USERS
DICTIONARY = "dictionary.txt"
TLS_DIR = "tls"
GITIGNORE = ".gitignore"  # "*": the credentials never show as untracked in a user's git checkout
GITIGNORE_TEXT = b"# written by vrsim: the bus's credentials, never to be committed\n*\n"
TLS_FILES = ("ca.pem", "router.pem", "router-key.pem")
TLS_HOSTS = ("localhost", "127.0.0.1", "::1")
TLS_VALID_DAYS = 825  # the longest validity common TLS clients accept for a server certificate
PASSWORD_BYTES = 24  # secrets.token_urlsafe: 32 characters of [A-Za-z0-9_-], never ':' or a newline
# Largest put or query body the router passes on (zenoh's low_pass_filter drops bigger ones before any
# service sees them): a lockstep pose batch is ~300 kB, a scenario ~1 MB; map/rate batches are the
# big ones.
MAX_BODY_BYTES = 64 * 1024 * 1024
MESSAGE_OVERHEAD_BYTES = 1024 * 1024  # a message's key expression, parameters and headers


# ------------------------------------------------------------------------------------------ grants
@dataclass(frozen=True)
class _Grant:
    """One ACL allow rule: these message kinds, in these flows, on key expressions these include."""

    messages: tuple[str, ...]
    flows: tuple[str, ...]
    key_exprs: tuple[str, ...]


def _everything(k: Keys) -> str:
    """Every key under the prefix."""
    return f"{k.prefix}/**"


def _publish(k: Keys, *keys: str) -> list[_Grant]:
    """Put on ``keys``. The router must also pass the publisher the subscribers' declarations
    (egress declare_subscriber): a zenoh client sends a put only when it knows of a matching
    subscriber, and a subscriber may declare a wildcard, so every declaration under the prefix."""
    return [_Grant(("put",), ("ingress",), keys),
            _Grant(("declare_subscriber",), ("egress",), (_everything(k),))]


def _subscribe(*keys: str) -> list[_Grant]:
    """Subscribe to ``keys`` and receive their puts."""
    return [_Grant(("declare_subscriber",), ("ingress",), keys), _Grant(("put",), ("egress",), keys)]


def _serve(*keys: str) -> list[_Grant]:
    """Declare a queryable on ``keys``, receive the queries on them and reply."""
    return [_Grant(("declare_queryable", "reply"), ("ingress",), keys), _Grant(("query",), ("egress",), keys)]


def _ask(k: Keys, *keys: str) -> list[_Grant]:
    """Query ``keys`` and receive the replies. A zenoh querier sends a query only when it knows of a
    matching queryable, so it also gets the queryables' declarations (which name only a key
    expression, as docs/api.md does) under the prefix."""
    return [_Grant(("query",), ("ingress",), keys), _Grant(("reply",), ("egress",), keys),
            _Grant(("declare_queryable",), ("egress",), (_everything(k),))]


def _alive(keys: Keys, service: str) -> list[_Grant]:
    """Declare this service's liveliness token."""
    return [_Grant(("liveliness_token",), ("ingress",), (keys.alive(service),))]


def _watch_alive(keys: Keys) -> list[_Grant]:
    """List and watch the liveliness tokens (``<prefix>/alive/*``)."""
    return [_Grant(("liveliness_query", "declare_liveliness_subscriber"), ("ingress",), (keys.alive_all,)),
            _Grant(("liveliness_token",), ("egress",), (keys.alive_all,))]


ROLES: dict[str, Callable[[Keys], list[_Grant]]] = {}


def _role(name: str):
    """Register a role: a function of the `Keys` returning its grants."""

    def register(fn: Callable[[Keys], list[_Grant]]):
        ROLES[name] = fn
        return fn

    return register


@_role("vehicle")
def _vehicle(k: Keys) -> list[_Grant]:
    return [*_publish(k, k.pose), *_serve(k.vehicle_ns), *_ask(k, k.control_step), *_alive(k, "vehicle")]


@_role("controller")
def _controller(k: Keys) -> list[_Grant]:
    return [*_publish(k, k.shaft, k.rate), *_serve(k.control_ns), *_alive(k, "controller")]


@_role("monitor")
def _monitor(k: Keys) -> list[_Grant]:
    # machine_ns (<prefix>/<machine>/*) serves `report` and answers unknown one-chunk keys there.
    return [*_subscribe(k.pose, k.shaft, k.rate), *_serve(k.machine_ns, k.monitor_ns), *_alive(k, "monitor")]


@_role("map")
def _map(k: Keys) -> list[_Grant]:
    return [*_serve(k.map_ns), *_alive(k, "map")]


@_role("scenario")
def _scenario(k: Keys) -> list[_Grant]:
    controls = (k.map_load, k.control_load, k.monitor_load, k.monitor_end, k.monitor_status,
                k.vehicle("start"), k.vehicle("stop"), k.vehicle("status"))
    # top_ns (<prefix>/*) answers unknown top-level keys with the list of vrsim keys.
    return [*_serve(k.scenario_ns, k.top_ns), *_ask(k, *controls), *_watch_alive(k), *_alive(k, "scenario")]


def _read_only_keys(k: Keys) -> tuple[str, ...]:
    """The keys whose queries change nothing: what a viewer may ask."""
    return (*_web_keys(k), k.vehicle("status"))


def _web_keys(k: Keys) -> tuple[str, ...]:
    """The read-only keys the web page asks (its map, the run's status, report and stored records)."""
    return (k.map_info, k.map_rate, k.report, k.monitor_status, k.monitor_run, k.monitor_records,
            k.scenario("status"))


@_role("operator")
def _operator(k: Keys) -> list[_Grant]:
    return [*_ask(k, _everything(k)), *_subscribe(_everything(k)), *_watch_alive(k)]


@_role("viewer")
def _viewer(k: Keys) -> list[_Grant]:
    return [*_ask(k, *_read_only_keys(k)), *_subscribe(_everything(k)), *_watch_alive(k)]


@_role("web")
def _web(k: Keys) -> list[_Grant]:
    # A viewer narrowed to what the page shows; its start and stop go through an operator session.
    return [*_ask(k, *_web_keys(k)), *_subscribe(k.pose, k.shaft, k.rate), *_alive(k, "web")]


USER_ROLES: dict[str, str] = {**{s: s for s in SERVICE_USERS}, "operator": "operator", "viewer": "viewer"}


def _acl_config(keys: Keys, user_roles: Mapping[str, str] | None = None) -> dict:
    """The router's ``access_control`` section: default deny, one subject and policy per user.

    Parameters
    ----------
    keys : Keys
        The prefix and machine the rules are written for.
    user_roles : mapping, optional
        User name -> role name in `ROLES` (default `USER_ROLES`).
    """
    user_roles = USER_ROLES if user_roles is None else user_roles
    rules, subjects, policies = [], [], []
    for user, role_name in user_roles.items():
        if role_name not in ROLES:
            raise ServiceError(f"user {user!r}: unknown role {role_name!r} "
                               f"(roles: {', '.join(sorted(ROLES))})")
        ids = []
        for i, grant in enumerate(ROLES[role_name](keys)):
            ids.append(f"{user}-{i}")
            rules.append({"id": ids[-1], "permission": "allow", "messages": list(grant.messages),
                          "flows": list(grant.flows), "key_exprs": list(grant.key_exprs)})
        subjects.append({"id": user, "usernames": [user]})
        policies.append({"id": user, "rules": ids, "subjects": [user]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


# ------------------------------------------------------------------------------------ state folder
@dataclass(frozen=True)
class SecurityState:
    """The private state folder: credentials of every user and, with TLS, the CA and router keys."""

    folder: str
    passwords: Mapping[str, str] = field(repr=False)
    tls: bool = False

    @property
    def dictionary_file(self) -> str:
        return os.path.join(self.folder, DICTIONARY)

    def tls_file(self, name: str) -> str:
        return os.path.join(self.folder, TLS_DIR, name)

    def config_file(self, user: str) -> str:
        """``<folder>/<user>.json5``: the user's complete client configuration."""
        return os.path.join(self.folder, f"{user}.json5")

    def password(self, user: str) -> str:
        if user not in self.passwords:
            raise ServiceError(f"{self.dictionary_file}: no user {user!r} "
                               f"(users: {', '.join(self.passwords)})")
        return self.passwords[user]


def prepare_state(folder: str = DEFAULT_STATE_DIR, tls: bool = False, rotate: bool = False,
                  users: tuple[str, ...] = USERS) -> SecurityState:
    """Create or check the private state folder and fill in what is missing (``vrsim serve all``).

    Passwords already in the dictionary are kept (an operator's or viewer's password stays valid
    across restarts) unless ``rotate``; missing users get a new random one. With ``tls``, a CA and a
    router certificate for `TLS_HOSTS` are generated when absent (or when ``rotate``).

    Raises
    ------
    ServiceError
        The folder or a file in it is not private (mode, owner, a symlink) or not readable.
    """
    folder = os.path.abspath(folder)
    _private_dir(folder, create=True)
    if not os.path.lexists(os.path.join(folder, GITIGNORE)):
        _write_private(os.path.join(folder, GITIGNORE), GITIGNORE_TEXT)
    passwords = {} if rotate else _read_dictionary(folder)
    for user in users:
        passwords.setdefault(user, secrets.token_urlsafe(PASSWORD_BYTES))
    _write_private(os.path.join(folder, DICTIONARY),
                  "".join(f"{u}:{p}\n" for u, p in passwords.items()).encode())
    if tls:
        _private_dir(os.path.join(folder, TLS_DIR), create=True)
        if rotate or not all(os.path.exists(os.path.join(folder, TLS_DIR, n)) for n in TLS_FILES):
            _write_tls(os.path.join(folder, TLS_DIR))
    return SecurityState(folder, passwords, tls)


def load_state(folder: str = DEFAULT_STATE_DIR) -> SecurityState:
    """The state folder as a client reads it (`vrsim query`, a service started by hand): no writes."""
    folder = os.path.abspath(folder)
    if not os.path.lexists(folder):
        raise ServiceError(f"state folder {folder}: does not exist; start `vrsim serve all` there, give "
                           "--state-dir, or use --insecure for an open bus")
    _private_dir(folder, create=False)
    passwords = _read_dictionary(folder)
    if not passwords:
        raise ServiceError(f"{os.path.join(folder, DICTIONARY)}: missing or empty")
    tls = os.path.lexists(os.path.join(folder, TLS_DIR, TLS_FILES[0]))
    return SecurityState(folder, passwords, tls)


def _private_dir(path: str, create: bool) -> None:
    if create and not os.path.lexists(path):
        try:
            os.mkdir(path, 0o700)
        except OSError as exc:
            raise ServiceError(f"state folder {path}: cannot create: {exc.strerror}") from None
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise ServiceError(f"state folder {path}: not a folder (a symlink or a file)")
    _check_private(path, st, "chmod 700")


def _check_private(path: str, st: os.stat_result, fix: str) -> None:
    if st.st_uid != os.getuid():
        raise ServiceError(f"{path}: owned by uid {st.st_uid}, not by this user ({os.getuid()}); refusing it")
    if st.st_mode & 0o077:
        raise ServiceError(f"{path}: mode {stat.S_IMODE(st.st_mode):04o} lets others in; `{fix} {path}` "
                           "or choose another --state-dir")


def _write_private(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` as a 0600 file, atomically, never through a symlink."""
    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except OSError as exc:
        if os.path.lexists(tmp):
            os.unlink(tmp)
        raise ServiceError(f"{path}: cannot write: {exc.strerror}") from None


def _read_private(path: str) -> bytes | None:
    """A private file's bytes (None when absent); refuses symlinks, other owners, open modes."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ServiceError(f"{path}: cannot open: {exc.strerror} (a symlink is refused)") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise ServiceError(f"{path}: not a regular file")
        _check_private(path, st, "chmod 600")
        return fh.read(1 << 20)


def _read_dictionary(folder: str) -> dict[str, str]:
    path = os.path.join(folder, DICTIONARY)
    data = _read_private(path)
    passwords: dict[str, str] = {}
    for n, line in enumerate((data or b"").decode("utf-8", "replace").splitlines(), 1):
        user, sep, password = line.partition(":")
        if not (sep and user and password):
            raise ServiceError(f"{path}: line {n} is not user:password")  # never echo a password
        passwords[user] = password
    return passwords


def _write_tls(folder: str) -> None:
    """A private CA and a router certificate for `TLS_HOSTS`, signed by it (ECDSA P-256)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "vrsim local CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(minutes=5))
          .not_valid_after(now + datetime.timedelta(days=TLS_VALID_DAYS))
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False,
                                       key_encipherment=False, data_encipherment=False, key_agreement=False,
                                       key_cert_sign=True, crl_sign=True, encipher_only=False,
                                       decipher_only=False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    names = [x509.IPAddress(ipaddress.ip_address(h)) if h[0].isdigit() or ":" in h else x509.DNSName(h)
             for h in TLS_HOSTS]
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "vrsim router")]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=TLS_VALID_DAYS))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256()))
    pem = serialization.Encoding.PEM
    _write_private(os.path.join(folder, "ca.pem"), ca.public_bytes(pem))
    _write_private(os.path.join(folder, "router.pem"), cert.public_bytes(pem))
    _write_private(os.path.join(folder, "router-key.pem"), key.private_bytes(
        pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))


# ------------------------------------------------------------------------------------ zenoh configs
def router_settings(state: SecurityState, keys: Keys, listen: list[str],
                    user_roles: Mapping[str, str] | None = None,
                    max_body_bytes: int = MAX_BODY_BYTES) -> dict[str, object]:
    """Configuration entries (path -> JSON value) that make a zenoh router enforce the security model.

    ``listen`` are the router's endpoints; with TLS each must be a ``tls/`` endpoint. Puts and
    queries under the prefix whose payload exceeds ``max_body_bytes`` are dropped by the router.
    Apply them with `apply_settings` over the router's other configuration.
    """
    _check_endpoints(state, listen, "listen")
    out: dict[str, object] = {
        "mode": "router",
        "listen/endpoints": list(listen),
        "transport/auth/usrpwd/dictionary_file": state.dictionary_file,
        "access_control": _acl_config(keys, user_roles),
        "low_pass_filter": [{"id": "vrsim-bodies", "messages": ["put", "query"],
                             "key_exprs": [_everything(keys)], "size_limit": max_body_bytes}],
        # A message is reassembled from its fragments before any filter sees it: past this size the
        # router drops the fragments instead of buffering them (zenoh's default is 1 GiB).
        "transport/link/rx/max_message_size": max_body_bytes + MESSAGE_OVERHEAD_BYTES,
    }
    if state.tls:
        out["transport/link/tls/listen_certificate"] = state.tls_file("router.pem")
        out["transport/link/tls/listen_private_key"] = state.tls_file("router-key.pem")
    return out


def _client_settings(state: SecurityState, user: str, connect: list[str]) -> dict[str, object]:
    """Configuration entries (path -> JSON value) that make a zenoh client of ``connect`` logged in
    as ``user``."""
    _check_endpoints(state, connect, "connect")
    return {"mode": "client", "connect/endpoints": list(connect), **credential_settings(state, user)}


def credential_settings(state: SecurityState, user: str) -> dict[str, object]:
    """The entries that log a session in as ``user``: user, password and, with TLS, the CA to trust."""
    out: dict[str, object] = {"transport/auth/usrpwd/user": user,
                              "transport/auth/usrpwd/password": state.password(user)}
    if state.tls:
        out["transport/link/tls/root_ca_certificate"] = state.tls_file("ca.pem")
    return out


def recorded_endpoints(state: SecurityState, user: str) -> list[str]:
    """The endpoints ``<folder>/<user>.json5`` connects to: where the router that wrote the state
    folder listens (empty when there is no such file)."""
    data = _read_private(state.config_file(user))
    if data is None:
        return []
    try:
        endpoints = json.loads(data)["connect"]["endpoints"]
    except (ValueError, KeyError, TypeError):
        raise ServiceError(f"{state.config_file(user)}: not a client configuration vrsim wrote") from None
    return [e for e in endpoints if isinstance(e, str)]


def _check_endpoints(state: SecurityState, endpoints: list[str], what: str) -> None:
    if not endpoints:
        raise ServiceError(f"{what}: no endpoint given")
    if state.tls:
        plain = [e for e in endpoints if not e.startswith("tls/")]
        if plain:
            raise ServiceError(f"{what} endpoint {plain[0]!r}: TLS is on, so every endpoint must be "
                               f"tls/HOST:PORT (the router's certificate names {', '.join(TLS_HOSTS)})")


def apply_settings(conf, settings: Mapping[str, object]):
    """Insert ``settings`` into a `zenoh.Config` (they override what it had); returns it."""
    for path, value in settings.items():
        conf.insert_json5(path, json.dumps(value))
    return conf


def _settings_document(settings: Mapping[str, object]) -> dict:
    """``settings`` as one nested JSON5 (here: JSON) document, what `zenoh.Config.from_file` reads."""
    doc: dict = {}
    for path, value in settings.items():
        *parents, leaf = path.split("/")
        node = doc
        for name in parents:
            node = node.setdefault(name, {})
        node[leaf] = value
    return doc


BASE_SETTINGS = {"scouting/multicast/enabled": False, "transport/shared_memory/enabled": False}


def write_client_configs(state: SecurityState, connect: list[str],
                         users: tuple[str, ...] = USERS) -> dict[str, str]:
    """Write ``<folder>/<user>.json5`` (0600) for each user: a complete client configuration.

    Returns user -> path. A plain zenoh program logs in with ``zenoh.Config.from_file(path)``, and
    ``vrsim serve NAME --zenoh-config path`` starts a service as that user.
    """
    out = {}
    for user in users:
        doc = _settings_document({**BASE_SETTINGS, **_client_settings(state, user, connect)})
        out[user] = state.config_file(user)
        _write_private(out[user], (json.dumps(doc, indent=2) + "\n").encode())
    return out
