"""A zenoh router that enforces vrsim's security model, for the security tests (until `vrsim serve all`
does it): ``python -m tests.integration.secure_router STATE_DIR ENDPOINT [--tls]``.

It prepares the state folder (credentials, TLS material, one client configuration per user), opens a
router-mode session with `services.bus.security.router_settings`, declares ``vrsim/alive/router`` as
``vrsim serve all`` does, prints ``ready`` and serves until its standard input closes.
"""

from __future__ import annotations

import argparse
import sys


def main() -> None:
    import zenoh

    from services.bus import security
    from services.bus.config import Keys
    from services.bus.serving import declare_alive

    parser = argparse.ArgumentParser()
    parser.add_argument("state_dir")
    parser.add_argument("endpoint")
    parser.add_argument("--tls", action="store_true")
    args = parser.parse_args()
    state = security.prepare_state(args.state_dir, tls=args.tls)
    security.write_client_configs(state, [args.endpoint])
    settings = {**security.BASE_SETTINGS, **security.router_settings(state, Keys(), [args.endpoint])}
    with zenoh.open(security.apply_settings(zenoh.Config(), settings)) as session:
        token = declare_alive(session, Keys(), "router")
        print("ready", flush=True)
        sys.stdin.read()
        token.undeclare()


if __name__ == "__main__":
    main()
