"""rosbag2 bags with MCAP storage for the dlo-vitac graph (no rclpy here).

What `ros2 bag record -s mcap` writes, without a ROS install: a bag directory with
``metadata.yaml`` (rosbag2 version 9) and one ``.mcap`` file holding CDR messages and
``ros2msg`` schemas, the RIHS01 type hashes and the publishers' offered QoS profiles. The
real ``ros2 bag info/play``, rosbags and Foxglove open it.

- :func:`make_typestore`: the ROS 2 Jazzy typestore plus the project's interfaces (dlo_msgs),
  registered from their installed ``.msg`` text found through ``AMENT_PREFIX_PATH``; any other
  installed type is registered on demand (:func:`register_type`).
- :class:`BagWriter`: adds connections, writes raw CDR bytes with receive timestamps in small
  chunks that reach the disk on every :meth:`BagWriter.flush` (crash-safe: a killed writer's
  bag is recoverable with ``dlo-bag-recover``), rolls to a new bag directory on request
  (``split=True``: ``<path>/<name>_0000``, ``_0001``, ...), treats a write error as final and
  still closes the bag with what it holds.
- :func:`read_messages`, :func:`bag_info`: read a bag (or a directory of rolled parts) for
  analysis: ``(topic, type, timestamp, message)``; a damaged bag is one :class:`BagError` line
  that names the recovery command.
"""

from __future__ import annotations

import contextlib
import heapq
import os
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rosbags.interfaces import (
    MessageDefinitionFormat,
    Nodetype,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from .mcap_file import CHUNK_SIZE, WRITER_NAME, ChunkedMcapWriter

BAG_VERSION = 9
DEFAULT_PACKAGES = ("dlo_msgs",)
METADATA = "metadata.yaml"


class BagError(RuntimeError):
    """A bag cannot be written or read (message says why and what to do)."""


class NotABagError(BagError):
    """The path does not exist or holds no bag (a user's mistake, not a damaged recording)."""


# Exit status of every bag tool (dlo-bag-info, dlo-bag-recover, dlo-analyze):
EXIT_OK = 0
EXIT_BAD_BAG = 1  # the bag is damaged (needs dlo-bag-recover), a part could not be recovered, or
#                   (dlo-analyze) a recomputed outcome differs from the recorded one
EXIT_USAGE = 2  # bad option, no such path, not a bag
EXIT_NO_TASK_STATE = 3  # dlo-analyze: a bag without /dlo/task/state (recorded from a robot driver)


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
                "and 'source scripts/env.sh'"
            )
    return typestore


def type_hash(typestore: Typestore, msgtype: str) -> str:
    """RIHS01 hash of ``msgtype`` (registering it from the ament index when needed)."""
    if not register_type(typestore, msgtype):
        raise BagError(
            f"unknown message type '{msgtype}': not in the Jazzy typestore and no installed .msg file under AMENT_PREFIX_PATH"
        )
    return typestore.hash_rihs01(msgtype)


def message_definition(typestore: Typestore, msgtype: str) -> tuple[str, str]:
    """(ros2msg definition, RIHS01 hash) of ``msgtype``: the full text with every nested type
    after a ``MSG: pkg/msg/Name`` separator, as ``ros2 bag record`` writes it. The one source of
    the schema text of the recorder's bags and of the Foxglove bridge's channels."""
    rihs01 = type_hash(typestore, msgtype)
    msgdef, _ = typestore.generate_msgdef(msgtype, ros_version=2)
    return msgdef, rihs01


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

RECOVER_COMMAND = "dlo-bag-recover"
RESERVE_FILE = ".dlo_reserve"


class BagWriteError(BagError):
    """Writing a bag failed (disk full, permission, I/O error); ``cause`` is the short reason."""

    def __init__(self, message: str, cause: str = "", errno: int | None = None) -> None:
        super().__init__(message)
        self.cause = cause or message
        self.errno = errno


def os_error_cause(err: OSError) -> str:
    """'no space left on device' for ENOSPC etc. (the strerror, lower case)."""
    text = os.strerror(err.errno) if err.errno else str(err)
    return text[:1].lower() + text[1:]


def recover_hint(path: str | os.PathLike) -> str:
    return f"run: {RECOVER_COMMAND} {path}"


@dataclass
class TopicSpec:
    """A topic as written to a bag."""

    topic: str
    msgtype: str
    qos: list[Qos] = field(default_factory=list)
    rihs01: str = ""
    msgdef: str = ""


def qos_yaml(qos: Sequence[Qos]) -> str:
    """Offered QoS profiles as the YAML text rosbag2 keeps in an MCAP channel's metadata."""
    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False).strip()


def bag_metadata(
    mcap_name: str,
    topics: Sequence[TopicSpec],
    counts: dict[str, int],
    start: int | None,
    end: int | None,
    custom: dict[str, str] | None = None,
) -> dict:
    """The ``rosbag2_bagfile_information`` (version 9) of a one-file MCAP bag."""
    count = sum(counts.get(t.topic, 0) for t in topics)
    start_ns = int(start) if count and start is not None else 0
    duration = int(end - start) if count and start is not None and end is not None else 0
    return {
        "version": BAG_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start_ns},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t.topic,
                    "type": t.msgtype,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": dump_qos_v9(list(t.qos)),
                    "type_description_hash": t.rihs01,
                },
                "message_count": counts.get(t.topic, 0),
            }
            for t in topics
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [mcap_name],
        "files": [
            {
                "path": mcap_name,
                "starting_time": {"nanoseconds_since_epoch": start_ns},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": dict(custom) if custom else None,
        "ros_distro": "jazzy",
    }


def write_metadata(part: Path, info: dict) -> None:
    """Write ``part/metadata.yaml`` atomically (temporary file, fsync, rename)."""
    text = yaml.safe_dump({"rosbag2_bagfile_information": info}, default_flow_style=False, sort_keys=False)
    tmp = part / (METADATA + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, part / METADATA)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


class _Reserve:
    """Disk space held back in a hidden file so that a bag can still be closed on a full disk."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = 0
        self._fd: int | None = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)

    def grow(self, size: int) -> None:
        if self._fd is not None and size > self.size:
            os.posix_fallocate(self._fd, 0, size)
            self.size = size

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)
            self.path.unlink(missing_ok=True)


class BagWriter:
    """Writes raw CDR messages to a rosbag2 MCAP bag, crash-safe, optionally rolled into parts.

    ``split=False``: ``path`` is the bag directory. ``split=True``: ``path`` is a directory of
    bags ``<path>/<name>_0000``, ``_0001``, ...; :meth:`roll` closes the current part (complete,
    with metadata.yaml) and the next write opens a new one. Every part lists every topic known
    so far.

    Messages are written in chunks of at most ``chunk_size`` bytes: a chunk goes to disk when it
    is full and on every :meth:`flush` (call it regularly, e.g. twice a second), so a killed
    writer loses at most the messages since the last flush and its bag is recoverable
    (``dlo-bag-recover``). A write error (disk full, I/O) raises :class:`BagWriteError` and is
    final: :meth:`close` then frees the disk space held in reserve and closes the bag with
    everything written before the error, pending chunk included when the space allows.
    ``counts`` are the messages on disk per topic.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        typestore: Typestore | None = None,
        *,
        split: bool = False,
        chunk_size: int = CHUNK_SIZE,
        fsync: bool = True,
        reserve: bool = True,
    ) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(
                f"output '{self.path}' exists already; rosbag2 bags are never overwritten: choose another path or delete it"
            )
        self.typestore = typestore if typestore is not None else make_typestore()
        self.split = split
        self.chunk_size = chunk_size
        self.fsync = fsync
        self.use_reserve = reserve
        self.topics: dict[str, TopicSpec] = {}
        self.parts: list[Path] = []
        self.custom_data: dict[str, str] = {}
        self.failed: BagWriteError | None = None
        self.lost: dict[str, int] = {}  # written to memory but never to disk (after a failure)
        self.complete = True  # every closed part has its metadata.yaml
        self._done: dict[str, int] = {}
        self._mcap: ChunkedMcapWriter | None = None
        self._channels: dict[str, int] = {}
        self._reserve: _Reserve | None = None
        self._chunks_seen = 0
        self._closed = False

    # topics
    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> TopicSpec:
        """Declare a topic (idempotent for the same type); returns its spec with hash/msgdef."""
        spec = self.topics.get(topic)
        if spec is not None:
            if spec.msgtype != msgtype:
                raise BagError(f"topic '{topic}' is already recorded as '{spec.msgtype}', not '{msgtype}'")
            return spec
        msgdef, rihs01 = message_definition(self.typestore, msgtype)
        spec = TopicSpec(topic, msgtype, list(qos), rihs01, msgdef)
        self.topics[topic] = spec
        if self._mcap is not None:
            self._connect(spec)
        return spec

    def add_topic_spec(self, spec: TopicSpec) -> TopicSpec:
        """Declare a topic with a given definition and hash (e.g. one read from another bag)."""
        known = self.topics.get(spec.topic)
        if known is not None:
            if known.msgtype != spec.msgtype:
                raise BagError(f"topic '{spec.topic}' is already recorded as '{known.msgtype}', not '{spec.msgtype}'")
            return known
        self.topics[spec.topic] = spec
        if self._mcap is not None:
            self._connect(spec)
        return spec

    def _connect(self, spec: TopicSpec) -> None:
        assert self._mcap is not None
        schema_id = next((s.id for s in self._mcap.schemas.values() if s.name == spec.msgtype), 0)
        if not schema_id:
            schema_id = self._mcap.add_schema(spec.msgtype, "ros2msg", spec.msgdef.encode())
        self._channels[spec.topic] = self._mcap.add_channel(
            spec.topic, schema_id, "cdr", {"offered_qos_profiles": qos_yaml(spec.qos), "topic_type_hash": spec.rihs01}
        )

    def _open(self) -> None:
        if self._closed:
            raise BagError(f"bag '{self.path}' is closed")
        if self.failed:
            raise self.failed
        if self.split:
            part = self.path / f"{self.path.name}_{len(self.parts):04d}"
        else:
            if self.parts:
                raise BagError("roll() needs split=True")
            part = self.path
        try:
            part.mkdir(parents=True, exist_ok=False)
            self.parts.append(part)
            if self.use_reserve:
                self._reserve = _Reserve(part / RESERVE_FILE)
            self._mcap = ChunkedMcapWriter(
                part / f"{part.name}.mcap", chunk_size=self.chunk_size, library=f"{WRITER_NAME} (rosbag2 v{BAG_VERSION})"
            )
            self._channels = {}
            self._chunks_seen = 0
            for spec in self.topics.values():
                self._connect(spec)
            self._ensure_reserve()
        except FileExistsError:
            raise BagError(
                f"output '{part}' exists already; rosbag2 bags are never overwritten: choose another path or delete it"
            ) from None
        except OSError as err:
            raise self._fail(err, f"cannot create the bag '{part}'") from None

    @property
    def is_open(self) -> bool:
        return self._mcap is not None

    def open(self) -> None:
        """Open the (first/next) bag now instead of on the first write."""
        if self._mcap is None:
            self._open()

    def _fail(self, err: OSError, what: str = "") -> BagWriteError:
        cause = os_error_cause(err)
        where = what or f"writing {self._mcap.path if self._mcap else self.path} failed"
        if self.failed is None:
            self.failed = BagWriteError(f"{where}: {cause}", cause, err.errno)
        return self.failed

    def _ensure_reserve(self) -> None:
        """Hold back enough space to append the pending chunk twice, the summary and metadata."""
        if self._reserve is None or self._mcap is None:
            return
        metadata = 4096 + 2048 * len(self.topics) + sum(len(k) + len(v) for k, v in self.custom_data.items())
        need = 2 * self.chunk_size + self._mcap.summary_size() + 2 * metadata
        if need > self._reserve.size:
            self._reserve.grow(max(need + need // 4, 256 * 1024))

    def write(self, topic: str, data: bytes | memoryview, timestamp: int) -> None:
        """Write one serialised (CDR) message received at ``timestamp`` [ns]."""
        if self.failed:
            raise self.failed
        if self._mcap is None:
            self._open()
        assert self._mcap is not None
        channel = self._channels.get(topic)
        if channel is None:
            raise BagError(f"topic '{topic}' was not added (add_topic first)")
        try:
            self._mcap.add_message(channel, int(timestamp), data)
            if len(self._mcap.chunk_indexes) != self._chunks_seen:
                self._chunks_seen = len(self._mcap.chunk_indexes)
                self._ensure_reserve()
        except OSError as err:
            raise self._fail(err) from None

    def flush(self) -> None:
        """Put every message written so far on disk (a complete chunk; fsync if enabled)."""
        if self._mcap is None or self.failed:
            return
        try:
            self._mcap.flush(fsync=self.fsync)
            self._chunks_seen = len(self._mcap.chunk_indexes)
            self._ensure_reserve()
        except OSError as err:
            raise self._fail(err) from None

    def _part_counts(self, pending: bool) -> dict[str, int]:
        assert self._mcap is not None
        counts = self._mcap.counts + (self._mcap.pending_counts if pending else Counter())
        return {topic: counts.get(cid, 0) for topic, cid in self._channels.items()}

    def _finish_part(self, mcap: ChunkedMcapWriter, part: Path, *, drop_pending: bool) -> None:
        if not mcap.finished:
            counts = self._part_counts(pending=not drop_pending)
            start, end = mcap.time_range(pending=not drop_pending)
            info = bag_metadata(mcap.path.name, list(self.topics.values()), counts, start, end, self.custom_data)
            serialized = yaml.safe_dump(info, default_flow_style=False, sort_keys=False)
            records = {"rosbag2": {"serialized_metadata": serialized}}
            if drop_pending:
                lost = mcap.finish_committed(records, fsync=self.fsync)
                for topic, cid in self._channels.items():
                    if lost.get(cid):
                        self.lost[topic] = self.lost.get(topic, 0) + lost[cid]
            else:
                mcap.finish(records, fsync=self.fsync)
        counts = self._part_counts(pending=False)
        start, end = mcap.time_range(pending=False)
        write_metadata(part, bag_metadata(mcap.path.name, list(self.topics.values()), counts, start, end, self.custom_data))

    def _close_part(self) -> None:
        mcap = self._mcap
        if mcap is None:
            return
        part = self.parts[-1]
        try:
            if self.failed and self._reserve is not None:
                self._reserve.release()
            try:
                self._finish_part(mcap, part, drop_pending=False)
            except OSError as err:
                self._fail(err)
                if self._reserve is not None:
                    self._reserve.release()
                try:  # with the reserve freed
                    self._finish_part(mcap, part, drop_pending=False)
                except OSError:
                    try:  # what is on disk, without the pending chunk
                        self._finish_part(mcap, part, drop_pending=True)
                    except OSError as last:
                        self.complete = False
                        raise BagWriteError(
                            f"cannot close the bag '{part}': {os_error_cause(last)}; every complete "
                            f"chunk is on disk: free some space, then {recover_hint(self.path)}",
                            self.failed.cause if self.failed else os_error_cause(last),
                            last.errno,
                        ) from None
        finally:
            for topic, n in self._part_counts(pending=False).items():
                self._done[topic] = self._done.get(topic, 0) + n
            mcap.close()
            if self._reserve is not None:
                self._reserve.release()
                self._reserve = None
            self._mcap = None
            self._channels = {}

    def roll(self) -> None:
        """Finish the current part; the next write starts a new one (``split=True`` only)."""
        if not self.split:
            raise BagError("roll() needs split=True")
        self._close_part()

    def close(self) -> None:
        """Finish the bag (idempotent). A bag nothing was written to is still created.

        After a write error the bag is closed with what could be saved and the error is raised
        again (:class:`BagWriteError`), so that no caller mistakes it for a complete recording.
        """
        if self._closed:
            return
        try:
            if self._mcap is None and not self.parts and not self.failed:
                self._open()
            self._close_part()
        finally:
            self._closed = True
        if self.failed:
            raise self.failed

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def counts(self) -> dict[str, int]:
        """Messages on disk per topic (every known topic, 0 included)."""
        counts = dict.fromkeys(self.topics, 0)
        for topic, n in self._done.items():
            counts[topic] = counts.get(topic, 0) + n
        if self._mcap is not None:
            for topic, n in self._part_counts(pending=False).items():
                counts[topic] = counts.get(topic, 0) + n
        return counts

    @property
    def written(self) -> int:
        return sum(self.counts.values())


# ---- reading --------------------------------------------------------------------------------


def _needs_recovery(path: Path, why: str) -> BagError:
    return BagError(f"'{path}' needs recovering: {why}; {recover_hint(path)}")


def bag_parts(path: str | os.PathLike) -> list[Path]:
    """The bag directories of ``path``: itself if it is a bag, else its rolled parts in order.

    A bag whose recorder was killed (an ``.mcap`` without ``metadata.yaml``) raises a
    :class:`BagError` that names the recovery command.
    """
    path = Path(path)
    if (path / METADATA).is_file():
        return [path]
    if path.is_dir():
        if any(path.glob("*.mcap")):
            raise _needs_recovery(path, f"its .mcap data has no {METADATA} (the recorder was killed or could not close the bag)")
        parts = sorted(p for p in path.iterdir() if p.is_dir() and ((p / METADATA).is_file() or any(p.glob("*.mcap"))))
        broken = [p.name for p in parts if not (p / METADATA).is_file()]
        if broken:
            raise _needs_recovery(path, f"part {broken[0]} has no {METADATA} (the recorder was killed or could not close it)")
        if parts:
            return parts
    if not path.exists():
        raise NotABagError(f"'{path}' does not exist")
    raise NotABagError(f"'{path}' is not a rosbag2 bag (no {METADATA}) nor a directory of bags")


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return (text[0] if text else type(err).__name__).rstrip(".")


class _Parts:
    """The rosbags readers of a bag's parts, opened; damaged parts raise a one-line BagError."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.parts = bag_parts(self.path)
        self.readers: list[Any] = []

    def __enter__(self) -> list[Any]:
        from rosbags.rosbag2 import Reader

        try:
            for part in self.parts:
                if not any(part.glob("*.mcap")):  # no data at all: nothing dlo-bag-recover could salvage either
                    raise NotABagError(f"'{part}' has a {METADATA} but no .mcap data: not an MCAP bag, and nothing to recover")
                try:
                    reader = Reader(part)
                    reader.open()
                except Exception as err:  # noqa: BLE001 - any damage: one line, the recovery command
                    raise _needs_recovery(
                        self.path,
                        f"{part.name} cannot be read ({_first_line(err)}; the recording was interrupted or the file cut short)",
                    ) from None
                self.readers.append(reader)
        except BaseException:
            self.__exit__()
            raise
        return self.readers

    def __exit__(self, *exc: object) -> None:
        for reader in self.readers:
            with contextlib.suppress(Exception):
                reader.close()
        self.readers = []


def _bag_typestore(connections: Sequence[Any], default: Typestore | None) -> Typestore:
    """A typestore with the bag's own message definitions (as rosbags' AnyReader builds it)."""
    types: dict[str, Any] = {}
    undefined = False
    for conn in connections:
        fmt, data = conn.msgdef.format, conn.msgdef.data
        if fmt == MessageDefinitionFormat.MSG and data:
            types.update(get_types_from_msg(data, conn.msgtype))
        elif fmt == MessageDefinitionFormat.IDL and data:
            sep = "=" * 80 + "\n"
            if data.startswith(f"{sep}IDL: "):
                for block in data.split(sep)[1:]:
                    types.update(get_types_from_idl(block.split("\n", 1)[1]))
            else:
                types.update(get_types_from_idl(data))
        else:
            undefined = True
    if undefined:
        store = default if default is not None else make_typestore()
        for conn in connections:
            register_type(store, conn.msgtype)
        return store
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store


def _graph_topics(available: Iterable[str], wanted: Iterable[str]) -> dict[str, str]:
    """Bag topic -> requested name. A requested topic the bag lacks is found under the one namespace
    the bag's graph ran in (``launch_graph.sh --namespace NS`` records ``/NS/dlo/...``)."""
    available = set(available)
    mapping = {t: t for t in wanted if t in available}
    prefixes: dict[str, list[str]] = {}
    for topic in set(wanted) - set(mapping):
        for name in available:
            prefix = name[: -len(topic)]
            if name.endswith(topic) and len(prefix) > 1 and prefix.startswith("/") and not prefix.endswith("/"):
                prefixes.setdefault(prefix, []).append(topic)
    if len(prefixes) == 1:
        ((prefix, topics),) = prefixes.items()
        mapping.update({prefix + t: t for t in topics})
    return mapping


@dataclass
class BagMessage:
    """One message of a bag: topic, type name, receive timestamp [ns], message or raw CDR."""

    topic: str
    msgtype: str
    timestamp: int
    msg: Any


def read_messages(
    path: str | os.PathLike, topics: Iterable[str] | None = None, *, raw: bool = False, typestore: Typestore | None = None
) -> Iterator[BagMessage]:
    """Iterate the messages of a bag (or of all its rolled parts) in timestamp order.

    ``raw=True`` yields the CDR bytes; otherwise rosbags messages (attribute access like the
    rclpy ones), decoded with the definitions recorded in the bag. ``topics`` filters by name;
    a bag recorded from a graph in a namespace (``/NS/dlo/...``) answers for ``/dlo/...`` (the
    messages carry the requested name). Any bag directory name works (also ``run.bag``). A
    damaged bag raises :class:`BagError` naming ``dlo-bag-recover``.
    """
    wanted = set(topics) if topics is not None else None
    bag = Path(path)
    with _Parts(bag) as readers:
        names = (
            {c.topic: c.topic for r in readers for c in r.connections}
            if wanted is None
            else _graph_topics((c.topic for r in readers for c in r.connections), wanted)
        )
        conns = [c for r in readers for c in r.connections if c.topic in names]
        if not conns:
            return
        try:
            store = None if raw else _bag_typestore(conns, typestore)
        except Exception as err:  # noqa: BLE001 - a broken definition in the bag
            raise BagError(f"'{bag}': its message definitions cannot be parsed: {_first_line(err)}") from None
        streams = []
        for reader in readers:
            mine = [c for c in conns if c in reader.connections]
            if mine:
                streams.append(reader.messages(connections=mine))
        merged = heapq.merge(*streams, key=lambda item: item[1])
        count = 0
        while True:
            try:
                conn, timestamp, data = next(merged)
            except StopIteration:
                return
            except Exception as err:  # noqa: BLE001 - damage inside an indexed file
                raise _needs_recovery(bag, f"reading stopped after {count} messages ({_first_line(err)})") from None
            if raw:
                msg = data
            else:
                try:
                    msg = store.deserialize_cdr(data, conn.msgtype)
                except Exception as err:  # noqa: BLE001
                    raise BagError(
                        f"'{bag}': message {count} on {conn.topic} cannot be decoded as {conn.msgtype}: {_first_line(err)}"
                    ) from None
            count += 1
            yield BagMessage(names[conn.topic], conn.msgtype, timestamp, msg)


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
    parts_ = _Parts(path)
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
