"""``imucald mqtt``: bridge the daemon's stream and status to an MQTT broker."""
from __future__ import annotations

import signal
import threading


def cmd_mqtt(args) -> int:
    from ..mqtt.bridge import Bridge
    from .service import daemon_config, setup_logging
    cfg, _ = daemon_config(args)
    setup_logging(cfg["log"]["level"])
    bridge = Bridge(cfg)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration is not None:
        t = threading.Timer(args.duration, stop.set)
        t.daemon = True
        t.start()
    return bridge.run(stop)
