"""rosbag2 bags with MCAP storage for the dlo-vitac graph, built on rosbags (no rclpy here).

What `ros2 bag record -s mcap` writes, without a ROS install: a bag directory with
``metadata.yaml`` (rosbag2 version 9) and one ``.mcap`` file holding CDR messages and
``ros2msg`` schemas, the RIHS01 type hashes and the publishers' offered QoS profiles. The
real ``ros2 bag info/play`` and Foxglove open it.

- :func:`make_typestore`: the ROS 2 Jazzy typestore plus the project's interfaces (dlo_msgs),
  registered from their installed ``.msg`` text found through ``AMENT_PREFIX_PATH``; any other
  installed type is registered on demand (:func:`register_type`).
- :class:`BagWriter`: adds connections, writes raw CDR bytes with receive timestamps, rolls to a
  new bag directory on request (``split=True``: ``<path>/<name>_0000``, ``_0001``, ...) and
  closes cleanly (``metadata.yaml`` is written only on close: rosbags buffers about 1 MiB).
- :func:`read_messages`, :func:`bag_info`: read a bag (or a directory of rolled parts) for
  analysis: ``(topic, type, timestamp, message)``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Nodetype,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

BAG_VERSION = 9
DEFAULT_PACKAGES = ("dlo_msgs",)
METADATA = "metadata.yaml"


class BagError(RuntimeError):
    """A bag cannot be written or read (message says why and what to do)."""


# ---- types ----------------------------------------------------------------------------------

def ament_prefixes() -> list[Path]:
    """Install prefixes from ``AMENT_PREFIX_PATH`` (first wins, as in the ament index)."""
    return [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]


def interface_file(msgtype: str) -> Path | None:
    """The installed ``share/<pkg>/msg/<Name>.msg`` of ``pkg/msg/Name``, or None."""
    parts = msgtype.split("/")
    if len(parts) == 2:  # "pkg/Name" (ROS 1 style) -> msg
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3:
        return None
    pkg, kind, name = parts
    for prefix in ament_prefixes():
        path = prefix / "share" / pkg / kind / f"{name}.msg"
        if path.is_file():
            return path
    return None


def _referenced(desc: Any) -> Iterator[str]:
    """Type names a field description refers to."""
    kind, detail = desc
    if kind == Nodetype.NAME:
        yield detail
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _referenced(detail[0])


def register_type(typestore: Typestore, msgtype: str) -> bool:
    """Register ``msgtype`` (and the types it uses) from the ament index if not yet known.

    Returns True when the type is known afterwards.
    """
    if msgtype in typestore.fielddefs:
        return True
    path = interface_file(msgtype)
    if path is None:
        return False
    types = get_types_from_msg(path.read_text(encoding="utf-8"), msgtype)
    for _consts, fields in types.values():
        for _name, desc in fields:
            for dep in _referenced(desc):
                if dep not in types and not register_type(typestore, dep):
                    return False
    typestore.register(types)
    return True


def register_package(typestore: Typestore, package: str) -> list[str]:
    """Register every installed message of ``package``; returns the type names found."""
    names: list[str] = []
    for prefix in ament_prefixes():
        msgdir = prefix / "share" / package / "msg"
        if msgdir.is_dir():
            names = [f"{package}/msg/{p.stem}" for p in sorted(msgdir.glob("*.msg"))]
            break
    for name in names:
        register_type(typestore, name)
    return names


def make_typestore(packages: Iterable[str] = DEFAULT_PACKAGES) -> Typestore:
    """ROS 2 Jazzy typestore with ``packages`` (default dlo_msgs) registered from their .msg files."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for package in packages:
        if not register_package(typestore, package):
            raise BagError(
                f"no installed messages of '{package}' under AMENT_PREFIX_PATH="
                f"{os.environ.get('AMENT_PREFIX_PATH', '')!r}; build ros_ws (scripts/setup.sh) "
                "and 'source scripts/env.sh'")
    return typestore


def type_hash(typestore: Typestore, msgtype: str) -> str:
    """RIHS01 hash of ``msgtype`` (registering it from the ament index when needed)."""
    if not register_type(typestore, msgtype):
        raise BagError(f"unknown message type '{msgtype}': not in the Jazzy typestore and no "
                       "installed .msg file under AMENT_PREFIX_PATH")
    return typestore.hash_rihs01(msgtype)


# ---- QoS ------------------------------------------------------------------------------------

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


# ---- writing --------------------------------------------------------------------------------

@dataclass
class TopicSpec:
    """A topic as written to a bag."""

    topic: str
    msgtype: str
    qos: list[Qos] = field(default_factory=list)
    rihs01: str = ""
    msgdef: str = ""


class BagWriter:
    """Writes raw CDR messages to a rosbag2 MCAP bag, optionally rolled into parts.

    ``split=False``: ``path`` is the bag directory. ``split=True``: ``path`` is a directory of
    bags ``<path>/<name>_0000``, ``_0001``, ...; :meth:`roll` closes the current part (complete,
    with metadata.yaml) and the next write opens a new one. Every part lists every topic known
    so far. Always :meth:`close` (also on signals): metadata.yaml is written only then.
    """

    def __init__(self, path: str | os.PathLike, typestore: Typestore | None = None, *,
                 split: bool = False) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"output '{self.path}' exists already; rosbag2 bags are never "
                           "overwritten: choose another path or delete it")
        self.typestore = typestore if typestore is not None else make_typestore()
        self.split = split
        self.topics: dict[str, TopicSpec] = {}
        self.counts: dict[str, int] = {}
        self.parts: list[Path] = []
        self.custom_data: dict[str, str] = {}
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self._closed = False

    # topics
    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> TopicSpec:
        """Declare a topic (idempotent for the same type); returns its spec with hash/msgdef."""
        spec = self.topics.get(topic)
        if spec is not None:
            if spec.msgtype != msgtype:
                raise BagError(f"topic '{topic}' is already recorded as '{spec.msgtype}', "
                               f"not '{msgtype}'")
            return spec
        rihs01 = type_hash(self.typestore, msgtype)
        msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        spec = TopicSpec(topic, msgtype, list(qos), rihs01, msgdef)
        self.topics[topic] = spec
        self.counts.setdefault(topic, 0)
        if self._writer is not None:
            self._connect(spec)
        return spec

    def _connect(self, spec: TopicSpec) -> None:
        assert self._writer is not None
        self._connections[spec.topic] = self._writer.add_connection(
            spec.topic, spec.msgtype, msgdef=spec.msgdef, rihs01=spec.rihs01,
            serialization_format="cdr", offered_qos_profiles=spec.qos)

    def _open(self) -> None:
        if self._closed:
            raise BagError(f"bag '{self.path}' is closed")
        if self.split:
            self.path.mkdir(parents=True, exist_ok=True)
            part = self.path / f"{self.path.name}_{len(self.parts):04d}"
        else:
            if self.parts:
                raise BagError("roll() needs split=True")
            part = self.path
        part.parent.mkdir(parents=True, exist_ok=True)
        writer = Writer(part, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        self._writer = writer
        self._connections = {}
        self.parts.append(part)
        for spec in self.topics.values():
            self._connect(spec)

    @property
    def is_open(self) -> bool:
        return self._writer is not None

    def open(self) -> None:
        """Open the (first/next) bag now instead of on the first write."""
        if self._writer is None:
            self._open()

    def write(self, topic: str, data: bytes | memoryview, timestamp: int) -> None:
        """Write one serialised (CDR) message received at ``timestamp`` [ns]."""
        if self._writer is None:
            self._open()
        assert self._writer is not None
        conn = self._connections.get(topic)
        if conn is None:
            raise BagError(f"topic '{topic}' was not added (add_topic first)")
        self._writer.write(conn, int(timestamp), data)
        self.counts[topic] += 1

    def _close_part(self) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        for key, value in self.custom_data.items():
            writer.set_custom_data(key, str(value))
        writer.close()

    def roll(self) -> None:
        """Finish the current part; the next write starts a new one (``split=True`` only)."""
        if not self.split:
            raise BagError("roll() needs split=True")
        self._close_part()

    def close(self) -> None:
        """Finish the bag (idempotent). A bag nothing was written to is still created."""
        if self._closed:
            return
        try:
            if self._writer is None and not self.parts:
                self._open()
            self._close_part()
        finally:
            self._closed = True

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def written(self) -> int:
        return sum(self.counts.values())


# ---- reading --------------------------------------------------------------------------------

def bag_parts(path: str | os.PathLike) -> list[Path]:
    """The bag directories of ``path``: itself if it is a bag, else its rolled parts in order."""
    path = Path(path)
    if (path / METADATA).is_file():
        return [path]
    if path.is_dir():
        parts = sorted(p for p in path.iterdir() if (p / METADATA).is_file())
        if parts:
            return parts
        if any(path.glob("*.mcap")) or any(path.glob("*/*.mcap")):
            raise BagError(f"'{path}' has .mcap data but no {METADATA}: the recorder was killed "
                           "without closing the bag (SIGKILL?); it is incomplete")
    raise BagError(f"'{path}' is not a rosbag2 bag (no {METADATA}) nor a directory of bags")


@dataclass
class BagMessage:
    """One message of a bag: topic, type name, receive timestamp [ns], message or raw CDR."""

    topic: str
    msgtype: str
    timestamp: int
    msg: Any


def read_messages(path: str | os.PathLike, topics: Iterable[str] | None = None, *,
                  raw: bool = False, typestore: Typestore | None = None) -> Iterator[BagMessage]:
    """Iterate the messages of a bag (or of all its rolled parts) in timestamp order.

    ``raw=True`` yields the CDR bytes; otherwise rosbags messages (attribute access like the
    rclpy ones). ``topics`` filters by name.
    """
    wanted = set(topics) if topics is not None else None
    default = typestore if typestore is not None else make_typestore()
    with AnyReader(bag_parts(path), default_typestore=default) as reader:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        for conn, timestamp, data in reader.messages(connections=conns):
            msg = data if raw else reader.deserialize(data, conn.msgtype)
            yield BagMessage(conn.topic, conn.msgtype, timestamp, msg)


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
    from rosbags.rosbag2 import Reader

    parts = bag_parts(path)
    topics: dict[str, TopicInfo] = {}
    files: list[Path] = []
    starts, ends, custom = [], [], []
    total = 0
    for part in parts:
        with Reader(part) as reader:
            storage = reader.storage
            files.extend(part / f["path"] for f in getattr(storage, "files", []))
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
                    topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, conn.msgcount,
                                                   conn.digest, qos)
                else:
                    info.count += conn.msgcount
    size = sum(f.stat().st_size for f in files if f.exists())
    size += sum((p / METADATA).stat().st_size for p in parts)
    return BagInfo(Path(path), parts, files, size, min(starts, default=0), max(ends, default=0),
                   total, topics, custom)


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
        lines.append(f"{head}Topic: {name:<{width}} | Type: {t.msgtype} | Count: {t.count} | "
                     "Serialization Format: cdr")
        if verbose:
            lines.append(" " * 21 + f"hash: {t.rihs01}")
            for q in t.qos:
                lines.append(" " * 21 + f"qos: {q.reliability.name.lower()}, "
                             f"{q.durability.name.lower()}, {q.history.name.lower()} "
                             f"depth {q.depth}")
    if not info.topics:
        lines.append("Topic information: (none)")
    if verbose:
        for i, c in enumerate(info.custom_data):
            if c:
                lines.append(f"Custom data [{info.parts[i].name}]: "
                             + ", ".join(f"{k}={v}" for k, v in sorted(c.items())))
    return "\n".join(lines)
