"""The Sparkplug B edge node's settings (the daemon's [mqtt] section), its counters, and
the check of its TLS CA file that the node and the daemon's preflight share; the node
itself is drivers/sparkplug_node.py."""

from __future__ import annotations

import ssl
from dataclasses import dataclass, field

#: How long the backlog holds DDATA while the broker is away: a broker restart (seconds)
#: fits many times over; a longer outage keeps the newest minute and counts the rest.
BACKLOG_S = 60.0


class SparkplugError(Exception):
    """The edge node cannot be set up (a TLS file that cannot be read)."""


def tls_ca_problem(path: str) -> str | None:
    """Why the TLS CA file `path` cannot be used (missing, unreadable, no PEM certificate
    in it), or None: loaded as the node loads it, into a client TLS context."""
    try:
        ssl.create_default_context(cafile=path)
    except ssl.SSLError as err:  # read, but not a certificate the TLS library can load
        return f"holds no CA certificate TLS can load ({err.reason or err})"
    except OSError as err:
        return f"cannot be read ({err.strerror or err})"
    return None


@dataclass(frozen=True, slots=True)
class SparkplugSettings:
    """Settings; the names match the [mqtt] section of the daemon's config."""

    host: str = "127.0.0.1"
    port: int = 1883
    group_id: str = "adxl-gateway"
    edge_node_id: str = "gateway"
    device_id: str = "axis"
    qos: int = 0
    rate_hz: float = 20.0
    keepalive_s: int = 10
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    tls_ca_file: str | None = None
    commands_enabled: bool = False
    #: Sparkplug 3.0 primary host application: wait for its STATE online before birth
    primary_host_id: str | None = None

    @property
    def backlog_len(self) -> int:
        return max(1, round(BACKLOG_S * self.rate_hz))


@dataclass(slots=True)
class NodeCounters:
    connects: int = 0
    births: int = 0
    ddata_made: int = 0  # the metric mqtt/ddata_count
    ddata_sent: int = 0  # handed to the MQTT client
    dropped: int = 0  # backlog overflow and a full client queue
    commands_done: int = 0
    commands_refused: int = 0  # commands disabled, or the daemon declined
    bad_payloads: int = 0
    host_offline_ends: int = 0  # sessions ended because the primary host said it is offline
