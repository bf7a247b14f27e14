"""Crash-safe MCAP writing and tolerant MCAP scanning (ros2 profile), without rclpy.

:class:`ChunkedMcapWriter` writes an MCAP file chunk by chunk. Messages collect in memory in the
pending chunk; :meth:`ChunkedMcapWriter.flush` appends that chunk and its message indexes to the
file in one go. An append that fails (disk full, I/O error, file size limit) is cut back, so the
file always ends on the last complete chunk:

- a writer that is killed (SIGKILL, OOM, power loss after an fsync) loses only its pending chunk;
  every complete chunk on disk is salvaged by :func:`scan_mcap` (``dlo-bag-recover``);
- a writer that hits a write error keeps its pending chunk for a retry
  (:meth:`~ChunkedMcapWriter.finish`), or finishes the file with what is on disk
  (:meth:`~ChunkedMcapWriter.finish_committed`): a complete, indexed MCAP either way.

:func:`scan_mcap` reads every complete record of a possibly truncated or damaged file: schemas,
channels and messages from whole chunks, and the complete messages of a cut uncompressed chunk.
The records are (de)serialised with the ``mcap`` package's record classes.
"""

from __future__ import annotations

import contextlib
import os
import struct
import zlib
from collections import Counter, defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
# The writer's name inside every bag: the MCAP header's ``library`` and the prefix of the metadata.yaml
# ``custom_data`` keys (``<name>.episodes``, ``<name>.recovered``). The package was called that before it was
# split (CHANGELOG.md); the name stays so that bags are written exactly as before.
WRITER_NAME = "dlo_tools"
CHUNK_SIZE = 256 * 1024  # bytes of records per chunk before it is appended to the file
_RECORD_HEAD = struct.Struct("<BQ")


class McapScanError(ValueError):
    """A file that is not an MCAP file at all (wrong magic, empty)."""


def _record_bytes(record) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


@dataclass
class _PendingChunk:
    """Records not yet on disk (schemas, channels, messages) and their message index."""

    builder: RecordBuilder = field(default_factory=RecordBuilder)
    index: dict[int, list[tuple[int, int]]] = field(default_factory=lambda: defaultdict(list))
    counts: Counter = field(default_factory=Counter)
    start: int | None = None
    end: int | None = None

    @property
    def size(self) -> int:
        return self.builder.count

    @property
    def messages(self) -> int:
        return sum(self.counts.values())


class ChunkedMcapWriter:
    """An MCAP file (profile ``ros2``) whose data section only ever ends on a complete chunk.

    ``add_schema``/``add_channel``/``add_message`` go to the pending chunk (memory); ``flush``
    appends it (automatically once it exceeds ``chunk_size``). ``counts``, ``start_time`` and
    ``end_time`` describe what is on disk; ``pending_counts`` what is still in memory.
    Every method that writes raises ``OSError`` on a write error, after cutting the file back.
    """

    def __init__(self, path: str | os.PathLike, *, library: str = WRITER_NAME, chunk_size: int = CHUNK_SIZE) -> None:
        self.path = Path(path)
        self.chunk_size = chunk_size
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.committed = 0  # bytes on disk, ending on a complete record
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunk_indexes: list[ChunkIndex] = []
        self.counts: Counter = Counter()  # messages on disk per channel id
        self.start_time: int | None = None
        self.end_time: int | None = None
        self.finished = False
        self._pending = _PendingChunk()
        self._append(MAGIC + _record_bytes(Header(profile="ros2", library=library)))

    # ---- building --------------------------------------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self.schemas) + 1, name=name, encoding=encoding, data=data)
        self.schemas[schema.id] = schema
        schema.write(self._pending.builder)
        return schema.id

    def add_channel(
        self, topic: str, schema_id: int, message_encoding: str = "cdr", metadata: dict[str, str] | None = None
    ) -> int:
        channel = Channel(
            id=len(self.channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            metadata=dict(metadata or {}),
            schema_id=schema_id,
        )
        self.channels[channel.id] = channel
        channel.write(self._pending.builder)
        return channel.id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes | memoryview, publish_time: int | None = None, sequence: int = 0
    ) -> None:
        """Add one message; appends the pending chunk when it is full (may raise OSError)."""
        pending = self._pending
        pending.index[channel_id].append((log_time, pending.builder.count))
        Message(
            channel_id=channel_id,
            log_time=log_time,
            data=bytes(data),
            publish_time=log_time if publish_time is None else publish_time,
            sequence=sequence,
        ).write(pending.builder)
        pending.counts[channel_id] += 1
        pending.start = log_time if pending.start is None else min(pending.start, log_time)
        pending.end = log_time if pending.end is None else max(pending.end, log_time)
        if pending.size >= self.chunk_size:
            self.flush()

    @property
    def pending_counts(self) -> Counter:
        return Counter(self._pending.counts)

    @property
    def pending_bytes(self) -> int:
        return self._pending.size

    def time_range(self, pending: bool = True) -> tuple[int | None, int | None]:
        """(first, last) log time on disk, and in the pending chunk if ``pending``."""
        times = [t for t in (self.start_time, self.end_time) if t is not None]
        if pending and self._pending.start is not None:
            times += [self._pending.start, self._pending.end]
        return (min(times), max(times)) if times else (None, None)

    # ---- writing ---------------------------------------------------------------------------
    def _append(self, data: bytes, fsync: bool = False) -> None:
        """Append ``data`` at the committed end; on failure cut the file back and re-raise."""
        if self._fd is None:
            raise ValueError(f"{self.path} is closed")
        view = memoryview(data)
        done = 0
        try:
            while done < len(view):
                done += os.write(self._fd, view[done:])
            if fsync:
                os.fsync(self._fd)
        except OSError:
            try:
                os.ftruncate(self._fd, self.committed)
                os.lseek(self._fd, self.committed, os.SEEK_SET)
            except OSError:
                pass
            raise
        finally:
            view.release()
        self.committed += len(data)

    def flush(self, fsync: bool = False) -> None:
        """Append the pending chunk (if it holds anything) and its message indexes."""
        pending = self._pending
        if pending.size == 0:
            if fsync and self._fd is not None:
                os.fsync(self._fd)
            return
        records = pending.builder.end()
        start = pending.start if pending.start is not None else 0
        end = pending.end if pending.end is not None else 0
        chunk = _record_bytes(
            Chunk(
                compression="",
                data=records,
                message_start_time=start,
                message_end_time=end,
                uncompressed_crc=zlib.crc32(records),
                uncompressed_size=len(records),
            )
        )
        chunk_start = self.committed
        offsets: dict[int, int] = {}
        indexes = bytearray()
        for channel_id, entries in pending.index.items():
            offsets[channel_id] = chunk_start + len(chunk) + len(indexes)
            indexes += _record_bytes(MessageIndex(channel_id=channel_id, records=entries))
        try:
            self._append(chunk + bytes(indexes), fsync)
        except OSError:
            pending.builder.write(records)  # kept whole for a retry
            raise
        self.chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=chunk_start,
                chunk_length=len(chunk),
                message_index_offsets=offsets,
                message_index_length=len(indexes),
                compression="",
                compressed_size=len(records),
                uncompressed_size=len(records),
            )
        )
        self.counts.update(pending.counts)
        if pending.start is not None:
            self.start_time = pending.start if self.start_time is None else min(self.start_time, pending.start)
            self.end_time = pending.end if self.end_time is None else max(self.end_time, pending.end)
        self._pending = _PendingChunk()

    def discard_pending(self) -> Counter:
        """Forget the pending chunk (after a write error that a retry could not fix)."""
        lost = self._pending.counts
        self._pending = _PendingChunk()
        return lost

    def summary_size(self) -> int:
        """Upper bound of the bytes :meth:`finish` appends besides the pending chunk."""
        schemas = sum(len(s.data) + len(s.name) + len(s.encoding) + 32 for s in self.schemas.values())
        channels = sum(
            64 + len(c.topic) + len(c.message_encoding) + sum(len(k) + len(v) + 8 for k, v in c.metadata.items())
            for c in self.channels.values()
        )
        chunks = (len(self.chunk_indexes) + 1) * (96 + 10 * max(1, len(self.channels)))
        return 512 + schemas + channels + chunks + 10 * len(self.channels)

    def finish(self, metadata: dict[str, dict[str, str]] | None = None, fsync: bool = True) -> None:
        """Append the pending chunk, the metadata records, the summary and the footer; close."""
        self.flush()
        self._finish(metadata or {}, fsync)

    def finish_committed(self, metadata: dict[str, dict[str, str]] | None = None, fsync: bool = True) -> Counter:
        """Finish with what is on disk: the pending chunk is dropped (its counts returned)."""
        lost = self.discard_pending()
        self._finish(metadata or {}, fsync)
        return lost

    def _finish(self, metadata: dict[str, dict[str, str]], fsync: bool) -> None:
        data = bytearray()
        metadata_indexes = []
        for name, values in metadata.items():
            record = _record_bytes(Metadata(name=name, metadata=dict(values)))
            metadata_indexes.append(MetadataIndex(offset=self.committed + len(data), length=len(record), name=name))
            data += record
        data += _record_bytes(DataEnd(data_section_crc=0))
        summary_start = self.committed + len(data)
        offsets = []

        def group(opcode: int, records: list) -> None:
            if records:
                start = self.committed + len(data)
                for record in records:
                    data.extend(_record_bytes(record))
                offsets.append(
                    SummaryOffset(group_opcode=opcode, group_start=start, group_length=self.committed + len(data) - start)
                )

        group(Opcode.SCHEMA, list(self.schemas.values()))
        group(Opcode.CHANNEL, list(self.channels.values()))
        group(Opcode.CHUNK_INDEX, self.chunk_indexes)
        group(Opcode.METADATA_INDEX, metadata_indexes)
        group(
            Opcode.STATISTICS,
            [
                Statistics(
                    message_count=sum(self.counts.values()),
                    schema_count=len(self.schemas),
                    channel_count=len(self.channels),
                    attachment_count=0,
                    metadata_count=len(metadata),
                    chunk_count=len(self.chunk_indexes),
                    message_start_time=self.start_time or 0,
                    message_end_time=self.end_time or 0,
                    channel_message_counts={cid: self.counts.get(cid, 0) for cid in self.channels},
                )
            ],
        )
        summary_offset_start = self.committed + len(data)
        for offset in offsets:
            data += _record_bytes(offset)
        data += _record_bytes(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=0))
        data += MAGIC
        self._append(bytes(data), fsync)
        self.finished = True
        self.close()

    def close(self) -> None:
        """Close the file descriptor (an unfinished file keeps its complete chunks)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)


# ---- scanning --------------------------------------------------------------------------------


@dataclass
class ScannedMessage:
    channel_id: int
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass
class McapScan:
    """What :func:`scan_mcap` found: definitions, and how the file ended."""

    path: Path
    size: int = 0
    profile: str = ""
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    messages: int = 0
    chunks: int = 0
    complete: bool = False  # the data section ended with DataEnd (or a footer)
    good_end: int = 0  # offset after the last complete record read (in a cut chunk too)
    problems: list[str] = field(default_factory=list)

    @property
    def discarded(self) -> int:
        """Bytes after the last complete record."""
        return 0 if self.complete else self.size - self.good_end


def _decompress(data: bytes, compression: str, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        try:
            from backports import zstd  # rosbags' own dependency (Python < 3.14)
        except ImportError:  # pragma: no cover - Python >= 3.14
            from compression import zstd  # type: ignore[no-redef]
        return zstd.decompress(data)
    if compression == "lz4":
        try:
            import lz4.frame
        except ImportError as err:
            raise ValueError("lz4-compressed chunk and no 'lz4' package installed") from err
        return lz4.frame.decompress(data)
    raise ValueError(f"unknown chunk compression {compression!r}")


def _body_stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(BytesIO(body))


def _inner_records(
    scan: McapScan, data: bytes, used: list[int] | None = None, definitions_only: bool = False
) -> Iterator[ScannedMessage]:
    """Schemas, channels and messages of a chunk's records; stops at an incomplete record.

    ``used[0]`` is set to the bytes of ``data`` taken by complete records.
    ``definitions_only``: a damaged chunk, keep the schemas and channels that parse.
    """
    pos = 0
    while pos + 9 <= len(data):
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        if pos + 9 + length > len(data):
            break
        body = data[pos + 9 : pos + 9 + length]
        pos += 9 + length
        if used is not None:
            used[0] = pos
        if definitions_only:
            if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                with contextlib.suppress(Exception):
                    for _ in _handle_record(scan, opcode, body, in_chunk=True):
                        pass
            continue
        yield from _handle_record(scan, opcode, body, in_chunk=True)


def _read_summary_definitions(scan: McapScan, f) -> None:
    """Schemas and channels from the summary section of a file that has its footer."""
    with contextlib.suppress(Exception):
        f.seek(-37, os.SEEK_END)
        tail = f.read(37)
        if tail[-8:] != MAGIC or tail[0] != Opcode.FOOTER:
            return
        summary_start = struct.unpack_from("<Q", tail, 9)[0]
        footer_start = scan.size - 37
        if not 8 < summary_start <= footer_start:
            return
        f.seek(summary_start)
        data = f.read(footer_start - summary_start)
        for _ in _inner_records(scan, data, definitions_only=True):
            pass


def _handle_record(scan: McapScan, opcode: int, body: bytes, in_chunk: bool = False) -> Iterator[ScannedMessage]:
    if opcode == Opcode.SCHEMA:
        schema = Schema.read(_body_stream(body))
        scan.schemas.setdefault(schema.id, schema)
    elif opcode == Opcode.CHANNEL:
        channel = Channel.read(_body_stream(body))
        scan.channels.setdefault(channel.id, channel)
    elif opcode == Opcode.MESSAGE:
        if len(body) < 22:
            raise ValueError(f"message record of {len(body)} bytes")
        channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
        scan.messages += 1
        yield ScannedMessage(channel_id, log_time, publish_time, sequence, body[22:])
    elif opcode == Opcode.METADATA and not in_chunk:
        meta = Metadata.read(_body_stream(body))
        scan.metadata[meta.name] = meta.metadata


def scan_mcap(path: str | os.PathLike) -> tuple[McapScan, Iterator[ScannedMessage]]:
    """Scan a possibly damaged MCAP file: ``(scan, messages)``.

    ``messages`` yields every complete message in file order; ``scan`` fills in as it goes
    (schemas, channels, where the readable data ends, problems met). A chunk whose CRC does not
    match is skipped (reported in ``scan.problems``); the complete messages of a cut
    uncompressed chunk are kept. Raises :class:`McapScanError` for a file that is not MCAP.
    """
    path = Path(path)
    scan = McapScan(path, size=path.stat().st_size)
    f = path.open("rb")
    magic = f.read(8)
    if magic != MAGIC:
        f.close()
        raise McapScanError(f"{path} is not an MCAP file" + (" (it is empty)" if not magic else " (wrong magic bytes)"))

    _read_summary_definitions(scan, f)
    f.seek(8)

    def messages() -> Iterator[ScannedMessage]:
        with f:
            scan.good_end = 8
            while True:
                head = f.read(9)
                if len(head) < 9:
                    break
                opcode, length = _RECORD_HEAD.unpack(head)
                if length > scan.size - scan.good_end - 9:  # cut (or garbage) record
                    if opcode == Opcode.CHUNK:
                        yield from _cut_chunk(scan, f.read())
                    else:
                        scan.problems.append(f"record (opcode 0x{opcode:02x}) cut at byte {scan.good_end}")
                    break
                body = f.read(length)
                if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    scan.complete = True
                    scan.good_end += 9 + length
                    break
                try:
                    if opcode == Opcode.HEADER:
                        scan.profile = Header.read(_body_stream(body)).profile
                    elif opcode == Opcode.CHUNK:
                        chunk = Chunk.read(_body_stream(body))
                        data = _decompress(chunk.data, chunk.compression, chunk.uncompressed_size)
                        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
                            scan.problems.append(f"chunk at byte {scan.good_end}: CRC mismatch, its messages skipped")
                            for _ in _inner_records(scan, data, definitions_only=True):
                                pass
                        else:
                            scan.chunks += 1
                            yield from _inner_records(scan, data)
                    else:
                        yield from _handle_record(scan, opcode, body)
                except Exception as err:  # noqa: BLE001 - a damaged record: report, keep scanning
                    scan.problems.append(f"record (opcode 0x{opcode:02x}) at byte {scan.good_end}: {err}")
                scan.good_end += 9 + length

    return scan, messages()


def _cut_chunk(scan: McapScan, rest: bytes) -> Iterator[ScannedMessage]:
    """Complete records of a chunk whose end is missing (uncompressed chunks only)."""
    name = 8 + 8 + 8 + 4 + 4  # after message start and end time, uncompressed size, CRC, name length
    if len(rest) < name:
        scan.problems.append(f"chunk cut at byte {scan.good_end} (its header is incomplete)")
        return
    (name_length,) = struct.unpack_from("<I", rest, name - 4)
    records = name + name_length + 8  # after the compression name and the records length
    if len(rest) < records:
        scan.problems.append(f"chunk cut at byte {scan.good_end} (its header is incomplete)")
        return
    compression = rest[name : name + name_length].decode(errors="replace")
    if compression:
        scan.problems.append(f"{compression}-compressed chunk cut at byte {scan.good_end}: its messages are lost")
        return
    before, used = scan.messages, [0]
    yield from _inner_records(scan, rest[records:], used)
    scan.problems.append(f"chunk cut at byte {scan.good_end}: kept its {scan.messages - before} complete message(s)")
    if used[0]:
        scan.good_end += 9 + records + used[0]
