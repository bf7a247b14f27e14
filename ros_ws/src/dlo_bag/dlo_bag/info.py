"""What a bag holds (``ros2 bag info``): topics, types, counts, hashes, QoS, time span and files,
read from the metadata only (no rclpy here)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from rosbags.interfaces import Qos

from .metadata import METADATA
from .reader import PartReaders


@dataclass
class TopicInfo:
    """Per-topic summary of a bag."""

    topic: str
    msgtype: str
    count: int
    rihs01: str
    qos: list[Qos]


@dataclass
class BagInfo:
    """Summary of a bag (or of its rolled parts)."""

    path: Path
    parts: list[Path]
    files: list[Path]
    size: int
    start_ns: int
    end_ns: int
    message_count: int
    topics: dict[str, TopicInfo]
    custom_data: list[dict[str, str]]

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0


def bag_info(path: str | os.PathLike) -> BagInfo:
    """Topics, types, counts, hashes, QoS, time span and files of a bag (reads metadata only)."""
    parts_ = PartReaders(path)
    topics: dict[str, TopicInfo] = {}
    files: list[Path] = []
    starts, ends, custom = [], [], []
    total = 0
    with parts_ as readers:
        for part, reader in zip(parts_.parts, readers, strict=True):
            storage = reader.storage
            files.extend(part / f["path"] for f in getattr(storage, "files", []) or [])
            if reader.message_count:
                starts.append(reader.start_time)
                ends.append(reader.end_time - 1)  # rosbags: end_time is after the last
            total += reader.message_count
            meta = getattr(storage, "metadata", None)
            custom.append(dict(getattr(meta, "custom", None) or {}))
            for conn in reader.connections:
                info = topics.get(conn.topic)
                qos = list(getattr(conn.ext, "offered_qos_profiles", []) or [])
                if info is None:
                    topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, conn.msgcount, conn.digest, qos)
                else:
                    info.count += conn.msgcount
    size = sum(f.stat().st_size for f in files if f.exists())
    size += sum((p / METADATA).stat().st_size for p in parts_.parts)
    return BagInfo(Path(path), parts_.parts, files, size, min(starts, default=0), max(ends, default=0), total, topics, custom)


def _human_size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} GiB"


def _stamp(ns: int) -> str:
    import datetime

    dt = datetime.datetime.fromtimestamp(ns / 1e9, tz=datetime.timezone.utc)
    return f"{dt:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} ({ns / 1e9:.9f})"


def format_info(info: BagInfo, *, verbose: bool = False) -> str:
    """``ros2 bag info``-like text."""
    lines = [
        f"Files:             {', '.join(str(f) for f in info.files)}",
        f"Bag size:          {_human_size(info.size)}",
        "Storage id:        mcap",
        f"Parts:             {len(info.parts)}",
        f"Duration:          {info.duration_ns / 1e9:.9f}s",
        f"Start:             {_stamp(info.start_ns)}",
        f"End:               {_stamp(info.end_ns)}",
        f"Messages:          {info.message_count}",
    ]
    width = max((len(t) for t in info.topics), default=0)
    for i, name in enumerate(sorted(info.topics)):
        t = info.topics[name]
        head = "Topic information: " if i == 0 else " " * 19
        lines.append(f"{head}Topic: {name:<{width}} | Type: {t.msgtype} | Count: {t.count} | Serialization Format: cdr")
        if verbose:
            lines.append(" " * 21 + f"hash: {t.rihs01}")
            for q in t.qos:
                lines.append(
                    " " * 21 + f"qos: {q.reliability.name.lower()}, "
                    f"{q.durability.name.lower()}, {q.history.name.lower()} "
                    f"depth {q.depth}"
                )
    if not info.topics:
        lines.append("Topic information: (none)")
    if verbose:
        for i, c in enumerate(info.custom_data):
            if c:
                lines.append(f"Custom data [{info.parts[i].name}]: " + ", ".join(f"{k}={v}" for k, v in sorted(c.items())))
    return "\n".join(lines)
