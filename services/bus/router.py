"""The router alone (``vrsim serve router``): routes between clients and serves no key of its own."""

from __future__ import annotations

import threading

from vrsim.services.bus.config import ServiceConfig
from vrsim.services.bus.serving import run_service


def main(config: ServiceConfig, stop: threading.Event | None = None) -> int:
    """Route until SIGINT/SIGTERM (or ``stop``)."""
    run_service("router", config.zenoh, lambda session: [], default_mode="router", stop=stop)
    return 0
