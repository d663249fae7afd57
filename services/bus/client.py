"""The client side: one query and its reply, and who is alive."""

from __future__ import annotations

import json

from vrsim.common import ServiceError
from vrsim.services.bus.config import QUERY_TIMEOUT_S, Keys, zenoh_reason
from vrsim.services.bus.serving import error_message


# ---------------------------------------------------------------------------------------- client
def request(session, selector: str, payload: bytes | None = None, timeout_s: float = QUERY_TIMEOUT_S,
            what: str | None = None, user: str | None = None) -> bytes:
    """One query, one reply: the reply's payload, or a `ServiceError` that says what was waited for.

    Raises when no service serves the key (zenoh answers at once with no reply; also when the router's
    access rules do not let ``user`` ask it: zenoh does not tell the two apart), when the reply does
    not come within ``timeout_s``, or when the service replied with an error (its message).
    """
    import zenoh

    what = what or selector
    kwargs = {"timeout": timeout_s, "target": zenoh.QueryTarget.BEST_MATCHING}
    if payload is not None:
        kwargs["payload"] = payload
    try:
        replies = list(session.get(selector, **kwargs))
    except zenoh.ZError as exc:  # e.g. an invalid key expression ("$", "#" ...)
        raise ServiceError(f"{what}: {zenoh_reason(exc)}") from None
    for reply in replies:
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
    if not replies:
        denied = f", or the user {user} is not allowed to ask it" if user else ""
        raise ServiceError(f"{what}: no reply: no service serves this key{denied} (is it running? "
                           "`vrsim query <prefix>/scenario/status` lists the services alive)")
    message = error_message(replies[0].err.payload.to_bytes())
    if message.lower().startswith("timeout"):
        raise ServiceError(f"{what}: no reply within {timeout_s:g} s (service busy or hung)")
    raise ServiceError(message)


def request_json(session, selector: str, payload: bytes | None = None,
                 timeout_s: float = QUERY_TIMEOUT_S, what: str | None = None):
    raw = request(session, selector, payload, timeout_s, what)
    try:
        return json.loads(raw)
    except ValueError:
        raise ServiceError(f"{what or selector}: reply is not JSON: {raw[:80]!r}") from None


def alive_services(session, keys: Keys, timeout_s: float = 1.0) -> list[str]:
    """Names of the services whose liveliness token is declared right now."""
    names = []
    base = keys.alive("")
    for reply in session.liveliness().get(keys.alive_all, timeout=timeout_s):
        if reply.ok is not None:
            key = str(reply.ok.key_expr)
            names.append(key[len(base):] if key.startswith(base) else key)
    return sorted(set(names))
