"""QoS profiles in bags: from rclpy's, to the YAML rosbag2 keeps, and what a recorder subscribes with
(no rclpy here: rclpy profiles are duck-typed)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import yaml
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.metadata import dump_qos_v9


def _enum_value(value: Any) -> int:
    return int(getattr(value, "value", value))


def _qos_time(duration: Any) -> QosTime:
    ns = getattr(duration, "nanoseconds", duration)
    ns = int(ns)
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def qos_from_profile(profile: Any) -> Qos:
    """rosbags ``Qos`` from an rclpy ``QoSProfile`` (duck-typed; the rmw enum values agree)."""
    return Qos(
        history=QosHistory(_enum_value(profile.history)),
        depth=int(profile.depth),
        reliability=QosReliability(_enum_value(profile.reliability)),
        durability=QosDurability(_enum_value(profile.durability)),
        deadline=_qos_time(profile.deadline),
        lifespan=_qos_time(profile.lifespan),
        liveliness=QosLiveliness(_enum_value(profile.liveliness)),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def subscription_qos(offered: Sequence[Qos]) -> tuple[QosReliability, QosDurability]:
    """Reliability and durability a recorder subscribes with to match every publisher.

    As rosbag2 does: reliable only if every publisher is reliable (a reliable subscription
    cannot match a best-effort publisher), transient-local only if every publisher is.
    """
    if offered and all(q.reliability == QosReliability.RELIABLE for q in offered):
        reliability = QosReliability.RELIABLE
    elif offered:
        reliability = QosReliability.BEST_EFFORT
    else:
        reliability = QosReliability.RELIABLE
    if offered and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered):
        durability = QosDurability.TRANSIENT_LOCAL
    else:
        durability = QosDurability.VOLATILE
    return reliability, durability


def qos_yaml(qos: Sequence[Qos]) -> str:
    """Offered QoS profiles as the YAML text rosbag2 keeps in an MCAP channel's metadata."""
    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False).strip()
