"""Playback logic without rclpy: message classes by type name, timing at a rate factor."""

from __future__ import annotations

from collections.abc import Sequence

from dlo_common.topics import message_class
from rosbags.interfaces import Qos, QosDurability, QosReliability

# The generated Python class of ``pkg/msg/Name``: the one resolver lives with the topic registry.
import_message_class = message_class


def playback_qos(offered: Sequence[Qos]) -> tuple[QosReliability, QosDurability]:
    """Publisher reliability/durability for a recorded topic: the recorded publishers' own
    (reliable unless every recorded publisher was best effort; transient-local if any was)."""
    if offered and all(q.reliability == QosReliability.BEST_EFFORT for q in offered):
        reliability = QosReliability.BEST_EFFORT
    else:
        reliability = QosReliability.RELIABLE
    if any(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered):
        durability = QosDurability.TRANSIENT_LOCAL
    else:
        durability = QosDurability.VOLATILE
    return reliability, durability


class Pacer:
    """Maps bag timestamps to wall-clock deadlines: relative timing kept, sped up by ``rate``.

    ``rate`` 1.0 = recorded speed, 2.0 = twice as fast, 0 = as fast as possible (no waiting).
    """

    def __init__(self, rate: float) -> None:
        if rate < 0:
            raise ValueError(f"rate must be >= 0 (1.0 = recorded speed, 0 = no waiting), got {rate}")
        self.rate = rate
        self._bag0: int | None = None
        self._wall0 = 0.0

    def start(self, bag_t0: int, wall_t0: float) -> None:
        """Anchor: bag time ``bag_t0`` [ns] is played at wall time ``wall_t0`` [s]."""
        self._bag0, self._wall0 = bag_t0, wall_t0

    def deadline(self, stamp: int) -> float:
        """Wall time [s] at which the message received at ``stamp`` [ns] is published."""
        if self._bag0 is None:
            raise RuntimeError("Pacer.start() first")
        if self.rate == 0:
            return self._wall0
        return self._wall0 + (stamp - self._bag0) / 1e9 / self.rate
