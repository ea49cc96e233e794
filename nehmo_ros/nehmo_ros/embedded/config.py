"""DDS domain and network configuration of the embedded runtime.

By default every participant binds to loopback only: interface 127.0.0.1, no multicast, unicast
discovery with the peer 127.0.0.1 and automatic participant indices (up to 32 participants per
domain on the machine). Nothing is sent off the machine. To widen it (environment variables,
read when the first node of a process is created):

- ``NEHMO_DDS_CONFIG``: a Cyclone DDS XML configuration, inline (starts with ``<``) or a path or
  ``file://`` URI; used as given.
- ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` (or ``SYSTEM_DEFAULT``): Cyclone's own defaults, which
  honour ``CYCLONEDDS_URI`` (multicast discovery on the default interface), as ROS 2 does.
  ``LOCALHOST`` (the default here), ``OFF`` and ``ROS_LOCALHOST_ONLY=1`` keep loopback only.
- ``ROS_DOMAIN_ID``: the DDS domain, 0..232 (default 0).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

#: Highest participant index tried by unicast discovery on loopback (Cyclone's default is 9).
MAX_AUTO_PARTICIPANT_INDEX = 32
MAX_DOMAIN_ID = 232  # ports of higher domains overflow 16 bits with the default port mapping

LOOPBACK_XML = f"""<?xml version="1.0" encoding="UTF-8"?>
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain Id="any">
    <General>
      <Interfaces>
        <NetworkInterface address="127.0.0.1"/>
      </Interfaces>
      <AllowMulticast>false</AllowMulticast>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>{MAX_AUTO_PARTICIPANT_INDEX}</MaxAutoParticipantIndex>
      <Peers>
        <Peer address="127.0.0.1"/>
      </Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
"""


class DdsConfigError(ValueError):
    """An environment variable of the DDS configuration holds an invalid value."""


@dataclass(frozen=True)
class DdsConfig:
    """Domain id, the Cyclone XML (None: Cyclone's defaults / CYCLONEDDS_URI), and why."""

    domain_id: int
    xml: str | None
    scope: str  # "loopback" | "NEHMO_DDS_CONFIG" | "cyclone-defaults"


def domain_id_from_env(environ: Mapping[str, str] | None = None) -> int:
    """``ROS_DOMAIN_ID`` (0 if unset); raises naming the variable, the rule and the value."""
    env = os.environ if environ is None else environ
    text = env.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise DdsConfigError(
            f"ROS_DOMAIN_ID must be an integer in [0, {MAX_DOMAIN_ID}]; got {text!r}"
        )
    return value


def dds_config(domain_id: int | None = None, environ: Mapping[str, str] | None = None) -> DdsConfig:
    """The configuration a new participant gets under the current environment."""
    env = os.environ if environ is None else environ
    if domain_id is None:
        domain_id = domain_id_from_env(env)
    elif not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise DdsConfigError(f"domain_id must be in [0, {MAX_DOMAIN_ID}]; got {domain_id}")
    explicit = env.get("NEHMO_DDS_CONFIG", "").strip()
    if explicit:
        if not explicit.startswith("<") and "://" not in explicit:
            path = Path(explicit).expanduser()
            if not path.is_file():
                raise DdsConfigError(f"NEHMO_DDS_CONFIG names no file: {explicit!r}")
            explicit = path.resolve().as_uri()
        return DdsConfig(domain_id, explicit, "NEHMO_DDS_CONFIG")
    scope = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
    valid = ("", "LOCALHOST", "OFF", "SUBNET", "SYSTEM_DEFAULT")
    if scope not in valid:
        raise DdsConfigError(
            f"ROS_AUTOMATIC_DISCOVERY_RANGE must be one of {list(valid[1:])}; got {scope!r}"
        )
    if scope in ("SUBNET", "SYSTEM_DEFAULT") and env.get("ROS_LOCALHOST_ONLY", "") != "1":
        return DdsConfig(domain_id, None, "cyclone-defaults")
    return DdsConfig(domain_id, LOOPBACK_XML, "loopback")
