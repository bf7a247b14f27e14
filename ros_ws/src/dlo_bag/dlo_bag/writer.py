"""Writing rosbag2 bags with MCAP storage (no rclpy here).

What `ros2 bag record -s mcap` writes, without a ROS install: a bag directory with
``metadata.yaml`` (rosbag2 version 9) and one ``.mcap`` file holding CDR messages and
``ros2msg`` schemas, the RIHS01 type hashes and the publishers' offered QoS profiles. The
real ``ros2 bag info/play``, rosbags and Foxglove open it.

:class:`BagWriter` adds connections, writes raw CDR bytes with receive timestamps in small
chunks that reach the disk on every :meth:`BagWriter.flush` (crash-safe: a killed writer's
bag is recoverable with ``dlo-bag-recover``), rolls to a new bag directory on request
(``split=True``: ``<path>/<name>_0000``, ``_0001``, ...), treats a write error as final and
still closes the bag with what it holds.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from rosbags.interfaces import Qos
from rosbags.typesys.store import Typestore

from .errors import BagError, recover_hint
from .mcap_file import CHUNK_SIZE, WRITER_NAME, ChunkedMcapWriter
from .metadata import BAG_VERSION, bag_metadata, write_metadata
from .qos import qos_yaml
from .typestore import make_typestore, message_definition

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


@dataclass
class TopicSpec:
    """A topic as written to a bag."""

    topic: str
    msgtype: str
    qos: list[Qos] = field(default_factory=list)
    rihs01: str = ""
    msgdef: str = ""


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
