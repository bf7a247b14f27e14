"""dlo_bag.mcap_file on its own (no rclpy, no bag directory): the file ChunkedMcapWriter writes is a valid,
indexed MCAP that the official ``mcap`` reader reads back exactly (every index, offset and statistic checked
against the records it points at), and scan_mcap reads every complete record of a file cut at ANY byte,
of a damaged chunk, of compressed chunks, and says what it found.
"""

from __future__ import annotations

import os
import struct
import zlib
from io import BytesIO

import pytest
from dlo_bag.mcap_file import MAGIC, WRITER_NAME, ChunkedMcapWriter, McapScanError, scan_mcap
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, Footer, Header, Message, MessageIndex, Metadata, SummaryOffset
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer

HEAD = struct.Struct("<BQ")


def records_at(data: bytes, start: int, end: int) -> list[tuple[int, int, int, bytes]]:
    """(offset, opcode, total length, body) of the records that tile data[start:end] exactly."""
    out, pos = [], start
    while pos < end:
        opcode, length = HEAD.unpack_from(data, pos)
        out.append((pos, opcode, 9 + length, data[pos + 9 : pos + 9 + length]))
        pos += 9 + length
    assert pos == end, (pos, end)
    return out


def record_at(data: bytes, offset: int) -> tuple[int, int, bytes]:
    opcode, length = HEAD.unpack_from(data, offset)
    return opcode, 9 + length, data[offset + 9 : offset + 9 + length]


def stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(BytesIO(body))


def check_indexes(data: bytes) -> dict:
    """Every index of the file agrees with the records it points at (the MCAP specification's summary):
    footer -> summary offsets -> groups; chunk indexes -> chunks and their message indexes -> messages;
    metadata indexes -> metadata. Returns {chunk offset: [(log_time, channel_id, absolute end of the
    message record)]}."""
    assert data[:8] == MAGIC and data[-8:] == MAGIC
    opcode, length, body = record_at(data, len(data) - 37)
    assert (opcode, length) == (Opcode.FOOTER, 29)
    footer = Footer.read(stream(body))
    if footer.summary_crc:  # 0: none; else the CRC of the summary up to the footer's summary_offset_start
        assert footer.summary_crc == zlib.crc32(data[footer.summary_start : len(data) - 12])
    list(StreamReader(BytesIO(data), validate_crcs=True).records)  # chunk and data section CRCs
    summary = records_at(data, footer.summary_start, footer.summary_offset_start)
    offsets = [
        SummaryOffset.read(stream(b))
        for _, op, _, b in records_at(data, footer.summary_offset_start, len(data) - 37)
        if op == Opcode.SUMMARY_OFFSET
    ]
    groups = {}
    pos = footer.summary_start
    for off in offsets:  # the groups tile the summary section, each of records of its opcode only
        assert off.group_start == pos
        inside = records_at(data, off.group_start, off.group_start + off.group_length)
        assert {op for _, op, _, _ in inside} == {off.group_opcode}
        groups[off.group_opcode] = inside
        pos += off.group_length
    assert pos == footer.summary_offset_start and sum(len(g) for g in groups.values()) == len(summary)
    # the data section ends with DataEnd right before the summary
    data_end = [(o, op) for o, op, n, _ in records_at(data, 8, footer.summary_start)][-1]
    assert data_end[1] == Opcode.DATA_END
    reader = make_reader(BytesIO(data))
    chunks = {}
    for chunk_index in reader.get_summary().chunk_indexes:
        opcode, length, body = record_at(data, chunk_index.chunk_start_offset)
        assert opcode == Opcode.CHUNK and length == chunk_index.chunk_length
        chunk = Chunk.read(stream(body))
        assert chunk.compression == chunk_index.compression == ""
        assert chunk.uncompressed_crc == zlib.crc32(chunk.data)
        assert chunk_index.compressed_size == chunk_index.uncompressed_size == chunk.uncompressed_size == len(chunk.data)
        inner_start = chunk_index.chunk_start_offset + length - len(chunk.data)
        messages = {}
        for offset, op, n, b in records_at(chunk.data, 0, len(chunk.data)):
            if op == Opcode.MESSAGE:
                m = Message.read(stream(b), len(b))
                messages[offset] = (m.log_time, m.channel_id, inner_start + offset + n)
        times = [t for t, _, _ in messages.values()]
        assert (chunk.message_start_time, chunk.message_end_time) == (min(times), max(times))
        assert (chunk_index.message_start_time, chunk_index.message_end_time) == (min(times), max(times))
        index_start = chunk_index.chunk_start_offset + length
        index_records = records_at(data, index_start, index_start + chunk_index.message_index_length)
        assert sorted(chunk_index.message_index_offsets.values()) == [o for o, _, _, _ in index_records]
        for channel_id, offset in chunk_index.message_index_offsets.items():
            opcode, _, body = record_at(data, offset)
            assert opcode == Opcode.MESSAGE_INDEX
            index = MessageIndex.read(stream(body))
            assert index.channel_id == channel_id
            assert index.records == [(t, o) for o, (t, c, _) in messages.items() if c == channel_id]
        assert {c for _, c, _ in messages.values()} == set(chunk_index.message_index_offsets)
        chunks[chunk_index.chunk_start_offset] = list(messages.values())
    for metadata_index in reader.get_summary().metadata_indexes:
        opcode, length, body = record_at(data, metadata_index.offset)
        assert opcode == Opcode.METADATA and length == metadata_index.length
        assert Metadata.read(stream(body)).name == metadata_index.name
    return chunks


def write_example(path, chunk_size: int = 400, metadata=None):
    """Two schemas, three channels (one with metadata), 12 messages out of log-time order, some with their
    own publish time and sequence, in several chunks (automatic and explicit flushes). Returns what was
    written: [(topic, log_time, publish_time, sequence, data)] in file order."""
    w = ChunkedMcapWriter(path, chunk_size=chunk_size)
    s1 = w.add_schema("dlo_msgs/msg/GripperState", "ros2msg", b"float64 x\n")
    s2 = w.add_schema("sensor_msgs/msg/Image", "ros2msg", b"uint32 height\n")
    assert (s1, s2) == (1, 2)  # schema id 0 means "no schema" in MCAP
    topics = {
        w.add_channel("/dlo/gripper/state", s1): "/dlo/gripper/state",
        w.add_channel("/dlo/camera/image", s2, metadata={"offered_qos_profiles": "- depth: 1"}): "/dlo/camera/image",
        w.add_channel("/dlo/empty", s1, message_encoding="json"): "/dlo/empty",
    }
    assert list(topics) == [1, 2, 3]
    written = []
    log_times = [500, 100, 300, 200, 900, 700, 800, 600, 1000, 1200, 1100, 400]
    for i, t in enumerate(log_times):
        channel = 1 + i % 2
        publish = None if i % 3 else t - 7
        payload = bytes([i]) * (5 + 3 * i)
        w.add_message(channel, t, payload, publish_time=publish, sequence=i * 11)
        written.append((topics[channel], t, t if publish is None else publish, i * 11, payload))
        if i == 5:
            w.flush()
    w.finish(metadata)
    return written


def test_the_writer_makes_an_indexed_mcap_the_mcap_reader_reads_exactly(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_example(path, metadata={"rosbag2": {"ros_distro": "jazzy"}, "other": {"a": "1", "b": "2"}})
    data = path.read_bytes()
    chunks = check_indexes(data)
    assert len(chunks) >= 3  # the explicit flush and at least one automatic one
    assert (os.stat(path).st_mode & 0o777) == 0o644 & ~_umask()
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        header = reader.get_header()
        assert (header.profile, header.library) == ("ros2", WRITER_NAME)
        in_file_order = [
            (c.topic, m.log_time, m.publish_time, m.sequence, m.data) for _, c, m in reader.iter_messages(log_time_order=False)
        ]
        assert in_file_order == written
        by_time = [(c.topic, m.log_time) for _, c, m in reader.iter_messages()]
        assert by_time == sorted(((t, lt) for t, lt, *_ in written), key=lambda x: x[1])
        schemas = {c.topic: s.name for s, c, _ in reader.iter_messages()}
        assert schemas == {"/dlo/gripper/state": "dlo_msgs/msg/GripperState", "/dlo/camera/image": "sensor_msgs/msg/Image"}
        summary = reader.get_summary()
        assert {c.topic: (c.schema_id, c.message_encoding, c.metadata) for c in summary.channels.values()} == {
            "/dlo/gripper/state": (1, "cdr", {}),
            "/dlo/camera/image": (2, "cdr", {"offered_qos_profiles": "- depth: 1"}),
            "/dlo/empty": (1, "json", {}),
        }
        stats = summary.statistics
        assert (
            stats.message_count,
            stats.schema_count,
            stats.channel_count,
            stats.attachment_count,
            stats.metadata_count,
            stats.chunk_count,
        ) == (12, 2, 3, 0, 2, len(chunks))
        assert (stats.message_start_time, stats.message_end_time) == (100, 1200)
        assert stats.channel_message_counts == {1: 6, 2: 6, 3: 0}
        assert {m.name: m.metadata for m in reader.iter_metadata()} == {
            "rosbag2": {"ros_distro": "jazzy"},
            "other": {"a": "1", "b": "2"},
        }
    scan, messages = scan_mcap(path)
    got = [(m.channel_id, m.log_time, m.publish_time, m.sequence, m.data) for m in messages]
    assert got == [({"/dlo/gripper/state": 1, "/dlo/camera/image": 2}[t], lt, pt, sq, d) for t, lt, pt, sq, d in written]
    assert (scan.complete, scan.discarded, scan.problems, scan.profile) == (True, 0, [], "ros2")
    assert (scan.messages, scan.chunks) == (12, len(chunks))
    assert {i: c.topic for i, c in scan.channels.items()} == {1: "/dlo/gripper/state", 2: "/dlo/camera/image", 3: "/dlo/empty"}
    assert {i: s.name for i, s in scan.schemas.items()} == {1: "dlo_msgs/msg/GripperState", 2: "sensor_msgs/msg/Image"}
    assert scan.metadata == {"rosbag2": {"ros_distro": "jazzy"}, "other": {"a": "1", "b": "2"}}


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_what_is_on_disk_and_what_is_pending(tmp_path, monkeypatch):
    w = ChunkedMcapWriter(tmp_path / "a.mcap", chunk_size=10**6)
    assert not w.finished and not w.counts and not w.chunk_indexes
    header_end = w.committed
    assert header_end == os.path.getsize(tmp_path / "a.mcap") > 8
    assert w.time_range() == (None, None) and w.pending_bytes == 0
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.add_message(1, 300, b"x")
    w.add_message(1, 100, b"y")
    w.add_message(1, 200, b"z")
    assert w.pending_counts == {1: 3} and not w.counts and w.committed == header_end
    assert w.time_range() == (100, 300) and w.time_range(pending=False) == (None, None)
    pending = w.pending_counts
    pending[1] += 5  # a copy
    assert w.pending_counts == {1: 3}
    w.flush()
    assert w.counts == {1: 3} and not w.pending_counts and w.pending_bytes == 0
    assert (w.start_time, w.end_time) == (100, 300) and w.committed == os.path.getsize(tmp_path / "a.mcap")
    w.add_message(1, 50, b"a")
    w.add_message(1, 400, b"b")
    assert w.time_range() == (50, 400) and w.time_range(pending=False) == (100, 300)
    w.flush()
    w.add_message(1, 250, b"c")
    assert w.time_range() == (50, 400)
    w.flush()
    assert (w.start_time, w.end_time) == (50, 400) and w.counts == {1: 6}
    # flush with nothing pending writes nothing; with fsync it still syncs
    synced = []
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd))
    size = os.path.getsize(tmp_path / "a.mcap")
    w.flush()
    assert synced == [] and os.path.getsize(tmp_path / "a.mcap") == size
    w.flush(fsync=True)
    assert len(synced) == 1 and os.path.getsize(tmp_path / "a.mcap") == size
    w.add_message(1, 260, b"d")
    w.flush(fsync=True)
    assert len(synced) == 2
    monkeypatch.undo()
    w.finish(fsync=False)
    assert w.finished and w._fd is None
    w.close()  # again: nothing happens
    with pytest.raises(ValueError, match="closed"):
        w._append(b"x")


def test_the_pending_chunk_is_appended_once_it_reaches_chunk_size(tmp_path):
    probe = ChunkedMcapWriter(tmp_path / "probe.mcap", chunk_size=10**6)
    probe.add_channel("/a", probe.add_schema("s", "ros2msg", b""))
    probe.add_message(1, 1, b"1234")
    full = probe.pending_bytes
    probe.close()
    for chunk_size, appended in ((full + 1, False), (full, True)):
        w = ChunkedMcapWriter(tmp_path / f"{chunk_size}.mcap", chunk_size=chunk_size)
        w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
        before = w.committed
        w.add_message(1, 1, b"1234")
        assert (w.committed > before, w.pending_bytes == 0, dict(w.counts)) == (
            (True, True, {1: 1}) if appended else (False, False, {})
        ), chunk_size
        w.close()


def test_finish_committed_drops_the_pending_chunk_and_still_makes_an_indexed_file(tmp_path):
    path = tmp_path / "a.mcap"
    w = ChunkedMcapWriter(path, chunk_size=10**6)
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.add_message(1, 10, b"kept")
    w.flush()
    w.add_message(1, 20, b"lost")
    w.add_message(1, 30, b"lost")
    lost = w.finish_committed({"m": {"k": "v"}}, fsync=False)
    assert lost == {1: 2}
    check_indexes(path.read_bytes())
    with path.open("rb") as f:
        reader = make_reader(f)
        assert [m.data for _, _, m in reader.iter_messages()] == [b"kept"]
        stats = reader.get_summary().statistics
        assert (stats.message_count, stats.message_start_time, stats.message_end_time, stats.metadata_count) == (1, 10, 10, 1)
    w2 = ChunkedMcapWriter(tmp_path / "b.mcap", chunk_size=10**6)
    w2.add_message(1, 5, b"x")
    assert w2.discard_pending() == {1: 1} and w2.pending_bytes == 0 and not w2.pending_counts


def test_an_empty_file_is_finished_valid(tmp_path):
    path = tmp_path / "a.mcap"
    w = ChunkedMcapWriter(path)
    w.finish(fsync=False)
    data = path.read_bytes()
    check_indexes(data)
    with path.open("rb") as f:
        stats = make_reader(f).get_summary().statistics
    assert (stats.message_count, stats.chunk_count, stats.message_start_time, stats.message_end_time) == (0, 0, 0, 0)
    scan, messages = scan_mcap(path)
    assert list(messages) == [] and scan.complete and scan.problems == []


def test_a_failed_append_cuts_the_file_back_and_keeps_the_pending_chunk(tmp_path, monkeypatch):
    path = tmp_path / "a.mcap"
    w = ChunkedMcapWriter(path, chunk_size=10**6)
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.add_message(1, 10, b"one")
    w.flush()
    size = os.path.getsize(path)
    w.add_message(1, 20, b"two" * 100)
    real_write = os.write
    calls = []

    def short_then_fail(fd, data):
        calls.append(len(data))
        if len(calls) == 1:
            return real_write(fd, bytes(data[:10]))  # a partial write...
        raise OSError(28, "No space left on device")  # ...then the disk is full

    monkeypatch.setattr(os, "write", short_then_fail)
    with pytest.raises(OSError):
        w.flush()
    monkeypatch.undo()
    assert os.path.getsize(path) == size == w.committed  # cut back to the last complete chunk
    assert w.pending_counts == {1: 1} and w.counts == {1: 1}
    w.flush()  # the retry appends the kept chunk whole, at the right place
    w.finish(fsync=False)
    check_indexes(path.read_bytes())
    with path.open("rb") as f:
        assert [m.data for _, _, m in make_reader(f).iter_messages()] == [b"one", b"two" * 100]
    # a write that succeeds in pieces (os.write may write less than asked) writes everything once
    path2 = tmp_path / "b.mcap"
    monkeypatch.setattr(os, "write", lambda fd, data: real_write(fd, bytes(data[:7])))
    w = ChunkedMcapWriter(path2, chunk_size=10**6)
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.add_message(1, 10, b"one")
    w.finish(fsync=False)
    monkeypatch.undo()
    check_indexes(path2.read_bytes())


def test_summary_size_bounds_what_finish_appends(tmp_path):
    w = ChunkedMcapWriter(tmp_path / "a.mcap", chunk_size=50)
    for k in range(12):
        w.add_schema(f"pkg/msg/Type{k}" * 3, "ros2msg", b"float64 x\n" * (k + 1))
    for k in range(30):
        w.add_channel(
            f"/dlo/topic/with/a/long/name/{k}" * 2,
            1 + k % 12,
            metadata={"offered_qos_profiles": "- history: 1\n  depth: 10\n" * 3, "topic_type_hash": "RIHS01_" + "a" * 64},
        )
    for i in range(200):
        w.add_message(1 + i % 30, i, b"x" * 20)
    w.flush()
    assert len(w.chunk_indexes) > 10
    bound, before = w.summary_size(), w.committed
    w.finish(fsync=False)
    assert w.committed - before <= bound
    # many long-named schemas and channels with much metadata in one chunk: each part of the bound must hold
    w = ChunkedMcapWriter(tmp_path / "b.mcap", chunk_size=10**6)
    for k in range(20):
        w.add_schema(f"some_package/msg/AFairlyLongName{k:02d}", "ros2msg", b"float64 x\n")
    for k in range(3):
        w.add_channel(
            f"/dlo/{k}",
            1 + k,
            metadata={"offered_qos_profiles": "- history: 1\n  depth: 10\n" * 10, "topic_type_hash": "RIHS01_" + "a" * 64},
        )
    w.add_message(1, 5, b"x")
    w.flush()
    bound, before = w.summary_size(), w.committed
    w.finish(fsync=False)
    assert w.committed - before <= bound
    # many channels with long topics and many small metadata entries
    w = ChunkedMcapWriter(tmp_path / "c.mcap", chunk_size=10**6)
    w.add_schema("p/msg/T", "ros2msg", b"x")
    for k in range(30):
        w.add_channel(f"/t{k}".ljust(60, "x"), 1, metadata={f"k{j}": "v" for j in range(10)})
    for _ in range(3):
        for k in range(30):
            w.add_message(k + 1, k, b"m")
        w.flush()
    bound, before = w.summary_size(), w.committed
    w.finish(fsync=False)
    assert w.committed - before <= bound


def test_a_file_cut_anywhere_gives_every_complete_message_and_where_the_good_part_ends(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_example(path, chunk_size=250, metadata={"m": {"k": "v"}})
    data = path.read_bytes()
    chunks = check_indexes(data)
    footer = Footer.read(stream(record_at(data, len(data) - 37)[2]))
    top = records_at(data, 8, footer.summary_start)
    data_end = top[-1][0] + top[-1][2]
    ends = [8] + [o + n for o, _, n, _ in top] + [e for msgs in chunks.values() for *_, e in msgs]
    # the schema and channel records inside chunks end a complete record too
    for offset, body in ((o, b) for o, op, _, b in top if op == Opcode.CHUNK):
        chunk = Chunk.read(stream(body))
        inner = offset + 9 + len(body) - len(chunk.data)
        ends += [inner + o + n for o, _, n, _ in records_at(chunk.data, 0, len(chunk.data))]
    message_ends = sorted(e for msgs in chunks.values() for *_, e in msgs)
    cut_path = tmp_path / "cut.mcap"
    # every record boundary and the bytes either side, every byte of each chunk's head, the whole file's end
    chunk_heads = [o + k for o, op, _, _ in top if op == Opcode.CHUNK for k in range(60)]
    cuts = sorted({c for e in ends for c in (e - 1, e, e + 1)} | set(chunk_heads) | {len(data) - 1, len(data)})
    for cut in (c for c in cuts if 8 <= c <= len(data)):
        cut_path.write_bytes(data[:cut])
        scan, messages = scan_mcap(cut_path)
        got = [(m.log_time, m.sequence, m.data) for m in messages]
        expected = [(t, sq, d) for (_, t, _, sq, d), e in zip(written, message_ends) if e <= cut]
        assert got == expected, cut
        if cut >= data_end:  # the readable part ends with DataEnd: the summary and footer are no data
            assert (scan.complete, scan.good_end, scan.discarded) == (True, data_end, 0), cut
        else:
            good = max(e for e in ends if e <= cut)
            assert (scan.complete, scan.good_end, scan.discarded, scan.size) == (False, good, cut - good, cut), cut
    # what it says about a cut chunk
    chunk_starts = [o for o, op, _, _ in top if op == Opcode.CHUNK]
    second = chunk_starts[1]
    cut_path.write_bytes(data[: second + 20])
    scan, messages = scan_mcap(cut_path)
    list(messages)
    assert scan.problems == [f"chunk cut at byte {second} (its header is incomplete)"]
    first_message_end = min(e for *_, e in chunks[second])
    cut_path.write_bytes(data[: first_message_end + 3])
    scan, messages = scan_mcap(cut_path)
    assert len(list(messages)) == len(chunks[chunk_starts[0]]) + 1
    assert scan.problems == [f"chunk cut at byte {second}: kept its 1 complete message(s)"]
    index_record = next(o for o, op, _, _ in top if op == Opcode.MESSAGE_INDEX)
    cut_path.write_bytes(data[: index_record + 12])
    scan, messages = scan_mcap(cut_path)
    list(messages)
    assert scan.problems == [f"record (opcode 0x{Opcode.MESSAGE_INDEX:02x}) cut at byte {index_record}"]


def test_a_damaged_chunk_is_skipped_its_definitions_kept_and_the_summary_supplies_the_rest(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_example(path, chunk_size=250)
    data = bytearray(path.read_bytes())
    chunks = check_indexes(bytes(data))
    first, second = sorted(chunks)[:2]
    # a payload byte of the second chunk changed: its CRC fails, its messages are skipped, the rest kept
    last_end = chunks[second][-1][2]
    data[last_end - 1] ^= 0xFF
    path.write_bytes(bytes(data))
    scan, messages = scan_mcap(path)
    got = [m.sequence for m in messages]
    skipped = {
        sq for (_, _, _, sq, _), e in zip(written, sorted(e for c in chunks.values() for *_, e in c)) if second < e < last_end + 1
    }
    assert got == [sq for _, _, _, sq, _ in written if sq not in skipped] and skipped
    assert scan.problems == [f"chunk at byte {second}: CRC mismatch, its messages skipped"]
    assert scan.messages == len(got)  # the skipped chunk's messages are not counted either
    assert scan.complete and set(scan.channels) == {1, 2, 3}
    # the first chunk (which holds every schema and channel) made unreadable: the summary supplies them
    data = bytearray(path.read_bytes())
    for k in range(first + 9 + 50, chunks[first][-1][2]):
        data[k] = 0xFF
    path.write_bytes(bytes(data))
    scan, messages = scan_mcap(path)
    list(messages)
    assert set(scan.channels) == {1, 2, 3} and set(scan.schemas) == {1, 2}
    assert scan.channels[2].metadata == {"offered_qos_profiles": "- depth: 1"}
    # without the footer (cut after DataEnd's start) the definitions of the damaged chunk are lost
    footer = Footer.read(stream(record_at(bytes(data), len(data) - 37)[2]))
    path.write_bytes(bytes(data[: footer.summary_start]))
    scan, messages = scan_mcap(path)
    list(messages)
    assert scan.channels == {} and scan.complete


def test_compressed_chunks_are_read_and_a_cut_one_is_reported_lost(tmp_path):
    for compression, name in ((CompressionType.ZSTD, "zstd"), (CompressionType.LZ4, "lz4")):
        path = tmp_path / f"{name}.mcap"
        with path.open("wb") as f:
            writer = Writer(f, chunk_size=200, compression=compression)
            writer.start(profile="ros2", library="test")
            schema = writer.register_schema("s", "ros2msg", b"")
            channel = writer.register_channel("/a", "cdr", schema)
            for i in range(30):
                writer.add_message(channel, log_time=i, data=bytes([i]) * 40, publish_time=i + 1, sequence=i)
            writer.add_metadata("m", {"k": "v"})
            writer.finish()
        scan, messages = scan_mcap(path)
        assert [(m.log_time, m.publish_time, m.sequence, m.data) for m in messages] == [
            (i, i + 1, i, bytes([i]) * 40) for i in range(30)
        ]
        assert scan.complete and scan.problems == [] and scan.chunks > 1 and scan.metadata == {"m": {"k": "v"}}
        data = path.read_bytes()
        reader_chunks = make_reader(BytesIO(data)).get_summary().chunk_indexes
        last = reader_chunks[-1]
        path.write_bytes(data[: last.chunk_start_offset + last.chunk_length - 5])
        scan, messages = scan_mcap(path)
        assert len(list(messages)) < 30
        assert scan.problems == [f"{name}-compressed chunk cut at byte {last.chunk_start_offset}: its messages are lost"]


def test_odd_records_are_reported_and_the_scan_goes_on(tmp_path):
    def record(opcode, body):
        return HEAD.pack(opcode, len(body)) + body

    from dlo_bag.mcap_file import _record_bytes

    path = tmp_path / "a.mcap"
    w = ChunkedMcapWriter(path, chunk_size=10**6)
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.add_message(1, 10, b"first")
    w.flush()
    w.close()
    good = path.read_bytes()
    short_message = record(Opcode.MESSAGE, b"\x01\x00" + b"\x00" * 10)  # 12 bytes, a message needs 22
    unknown = _record_bytes(
        Chunk(
            message_start_time=0, message_end_time=0, uncompressed_size=3, uncompressed_crc=0, compression="brotli", data=b"abc"
        )
    )
    top_message = record(Opcode.MESSAGE, struct.pack("<HIQQ", 1, 7, 20, 21) + b"second")
    metadata = _record_bytes(Metadata(name="top", metadata={"k": "v"}))
    path.write_bytes(good + short_message + unknown + top_message + metadata)
    scan, messages = scan_mcap(path)
    assert [(m.log_time, m.publish_time, m.sequence, m.data) for m in messages] == [(10, 10, 0, b"first"), (20, 21, 7, b"second")]
    assert scan.problems == [
        f"record (opcode 0x05) at byte {len(good)}: message record of 12 bytes",
        f"record (opcode 0x06) at byte {len(good) + len(short_message)}: unknown chunk compression 'brotli'",
    ]
    assert scan.metadata == {"top": {"k": "v"}} and not scan.complete and scan.discarded == 0
    assert scan.good_end == scan.size
    # metadata inside a chunk is not the file's
    in_chunk = bytearray()
    in_chunk += metadata
    chunk = _record_bytes(
        Chunk(
            message_start_time=0,
            message_end_time=0,
            uncompressed_size=len(in_chunk),
            uncompressed_crc=zlib.crc32(bytes(in_chunk)),
            compression="",
            data=bytes(in_chunk),
        )
    )
    path.write_bytes(good + chunk)
    scan, messages = scan_mcap(path)
    list(messages)
    assert scan.metadata == {} and scan.problems == [] and scan.chunks == 2
    # a chunk without a CRC (0) is not checked
    chunk = _record_bytes(
        Chunk(
            message_start_time=0,
            message_end_time=0,
            uncompressed_size=len(top_message),
            uncompressed_crc=0,
            compression="",
            data=top_message,
        )
    )
    path.write_bytes(good + chunk)
    scan, messages = scan_mcap(path)
    assert [m.data for m in messages] == [b"first", b"second"] and scan.problems == []


def test_not_an_mcap_file(tmp_path):
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(McapScanError, match=r"is not an MCAP file \(it is empty\)"):
        scan_mcap(empty)
    wrong = tmp_path / "wrong.mcap"
    wrong.write_bytes(b"\x89MCAP1\r\n" + b"\x00" * 40)
    with pytest.raises(McapScanError, match=r"is not an MCAP file \(wrong magic bytes\)"):
        scan_mcap(wrong)
    only_magic = tmp_path / "magic.mcap"
    only_magic.write_bytes(MAGIC)
    scan, messages = scan_mcap(only_magic)
    assert list(messages) == [] and scan.good_end == 8 and scan.discarded == 0 and not scan.complete


def test_a_chunk_of_definitions_only(tmp_path):
    """Schemas and channels flushed before any message: a chunk without messages (times 0), no message index."""
    path = tmp_path / "a.mcap"
    w = ChunkedMcapWriter(path, chunk_size=10**6)
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.flush()
    assert w.time_range() == (None, None) and (w.start_time, w.end_time) == (None, None) and len(w.chunk_indexes) == 1
    w.add_message(1, 40, b"m")
    w.finish(fsync=False)
    data = path.read_bytes()
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    first = summary.chunk_indexes[0]
    assert (first.message_start_time, first.message_end_time, first.message_index_offsets, first.message_index_length) == (
        0,
        0,
        {},
        0,
    )
    assert (summary.statistics.message_start_time, summary.statistics.message_end_time) == (40, 40)
    chunk = Chunk.read(stream(record_at(data, first.chunk_start_offset)[2]))
    assert (chunk.message_start_time, chunk.message_end_time) == (0, 0)
    scan, messages = scan_mcap(path)
    assert [m.data for m in messages] == [b"m"] and scan.chunks == 2 and set(scan.channels) == {1}


def test_finish_closes_the_file_descriptor(tmp_path):
    w = ChunkedMcapWriter(tmp_path / "a.mcap")
    fd = w._fd
    os.fstat(fd)
    w.finish(fsync=False)
    with pytest.raises(OSError):
        os.fstat(fd)


def test_a_cut_chunk_keeps_a_complete_record_that_ends_exactly_at_the_cut(tmp_path):
    from dlo_bag.mcap_file import _record_bytes

    good = MAGIC + _record_bytes(Header(profile="ros2", library="x"))
    message = HEAD.pack(Opcode.MESSAGE, 22 + 2) + struct.pack("<HIQQ", 1, 3, 7, 7) + b"ab"
    empty = HEAD.pack(0x7F, 0)  # a record of an unknown opcode and no body: 9 bytes
    records = message + empty + message
    chunk = _record_bytes(
        Chunk(
            message_start_time=7,
            message_end_time=7,
            uncompressed_size=len(records),
            uncompressed_crc=zlib.crc32(records),
            compression="",
            data=records,
        )
    )
    path = tmp_path / "a.mcap"
    cut = len(good) + len(chunk) - len(message)  # the chunk cut right after the 9-byte record
    path.write_bytes((good + chunk)[:cut])
    scan, messages = scan_mcap(path)
    assert [m.data for m in messages] == [b"ab"]
    assert scan.good_end == cut and scan.discarded == 0


def test_summary_size_bounds_what_finish_appends_at_its_tightest(tmp_path):
    """summary_size() is an upper bound of what finish() appends besides the pending chunk, also where its
    allowances are used up: every channel in every chunk (each chunk index lists them all), a pending chunk at
    finish (its chunk index is in the summary too), channels with long message encodings and many schemas with
    a long encoding (both counted by their length, not by an allowance)."""

    def appended_besides_the_pending_chunk(w):
        bound, before = w.summary_size(), w.committed
        w.flush(fsync=False)  # what finish() appends first: the pending chunk and its message indexes
        chunk = w.committed - before
        w.finish(fsync=False)
        return w.committed - before - chunk, bound

    cases = (
        ("many_chunks", 30, 10, "cdr", 1, "ros2msg"),
        ("long_encodings", 60, 2, "application/x-dlo-" + "e" * 18, 1, "ros2msg"),
        ("longer_encodings", 60, 2, "application/x-dlo-" + "e" * 27, 1, "ros2msg"),  # beyond the allowance
        ("many_jsonschemas", 1, 1, "cdr", 1000, "jsonschema"),
    )
    for name, channels, chunks, encoding, schemas, schema_encoding in cases:
        w = ChunkedMcapWriter(tmp_path / f"{name}.mcap", chunk_size=10**9)
        for k in range(schemas):
            w.add_schema(f"p/msg/T{k}", schema_encoding, b"x")
        for k in range(channels):
            w.add_channel(f"/t{k}", 1, message_encoding=encoding)
        for j in range(chunks):
            for k in range(channels):
                w.add_message(k + 1, 100 * j + k, b"m")
            if j < chunks - 1:
                w.flush()
        assert w.pending_counts == {k + 1: 1 for k in range(channels)}
        appended, bound = appended_besides_the_pending_chunk(w)
        assert appended <= bound, name
        check_indexes((tmp_path / f"{name}.mcap").read_bytes())


def test_a_message_without_payload_is_a_complete_message(tmp_path):
    """A message of no data (22 bytes of record body: channel, sequence and the two times) is a complete message:
    written, read back by the mcap reader and by scan_mcap, also from a cut chunk."""
    path = tmp_path / "a.mcap"
    w = ChunkedMcapWriter(path, chunk_size=10**6)
    w.add_channel("/a", w.add_schema("s", "ros2msg", b""))
    w.add_message(1, 10, b"", publish_time=11, sequence=3)
    w.add_message(1, 20, b"x")
    w.flush()
    size_one_chunk = w.committed
    w.finish(fsync=False)
    data = path.read_bytes()
    check_indexes(data)
    with path.open("rb") as f:
        assert [m.data for _, _, m in make_reader(f).iter_messages()] == [b"", b"x"]
    scan, messages = scan_mcap(path)
    assert [(m.log_time, m.publish_time, m.sequence, m.data) for m in messages] == [(10, 11, 3, b""), (20, 20, 0, b"x")]
    assert scan.problems == [] and scan.messages == 2
    # the chunk cut right after the empty message (its record is 9 + 22 bytes)
    chunk_start = next(o for o, op, _, _ in records_at(data, 8, size_one_chunk) if op == Opcode.CHUNK)
    chunk = Chunk.read(stream(record_at(data, chunk_start)[2]))
    inner = chunk_start + record_at(data, chunk_start)[1] - len(chunk.data)
    empty_end = next(inner + o + n for o, op, n, _ in records_at(chunk.data, 0, len(chunk.data)) if op == Opcode.MESSAGE)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:empty_end])
    scan, messages = scan_mcap(cut)
    assert [m.data for m in messages] == [b""] and scan.good_end == empty_end and scan.discarded == 0


def test_a_cut_chunk_whose_compression_name_is_damaged_does_not_stop_the_scan(tmp_path):
    """The compression name of a cut chunk that is not UTF-8 (damaged bytes) is still reported, as a compressed
    chunk whose messages are lost; the messages before it are kept and the scan ends normally."""
    from dlo_bag.mcap_file import _record_bytes

    good = MAGIC + _record_bytes(Header(profile="ros2", library="x"))
    message = HEAD.pack(Opcode.MESSAGE, 22 + 2) + struct.pack("<HIQQ", 1, 3, 7, 7) + b"ab"
    first = _record_bytes(
        Chunk(
            message_start_time=7,
            message_end_time=7,
            uncompressed_size=len(message),
            uncompressed_crc=zlib.crc32(message),
            compression="",
            data=message,
        )
    )
    chunk = bytearray(
        _record_bytes(
            Chunk(
                message_start_time=7,
                message_end_time=7,
                uncompressed_size=len(message),
                uncompressed_crc=0,
                compression="zstd",
                data=message * 3,
            )
        )
    )
    name_at = chunk.index(b"zstd")
    chunk[name_at : name_at + 4] = b"\xff\xfez\xc3"  # not UTF-8
    path = tmp_path / "a.mcap"
    path.write_bytes(good + first + bytes(chunk[:-10]))
    scan, messages = scan_mcap(path)
    assert [m.data for m in messages] == [b"ab"]
    assert scan.problems == [f"\ufffd\ufffdz\ufffd-compressed chunk cut at byte {len(good) + len(first)}: its messages are lost"]
    assert scan.good_end == len(good) + len(first) and not scan.complete


def test_a_chunk_cut_inside_its_header_is_reported_as_such(tmp_path):
    """A chunk cut anywhere before its records begin (in the times, sizes, compression name or records length)
    is reported as a chunk whose header is incomplete, compressed or not: never as an uncompressed chunk with
    no message, nor under a cut-off compression name; the messages before it are kept."""
    from dlo_bag.mcap_file import _record_bytes

    good = MAGIC + _record_bytes(Header(profile="ros2", library="x"))
    message = HEAD.pack(Opcode.MESSAGE, 22 + 2) + struct.pack("<HIQQ", 1, 3, 7, 7) + b"ab"
    first = _record_bytes(
        Chunk(
            message_start_time=7,
            message_end_time=7,
            uncompressed_size=len(message),
            uncompressed_crc=zlib.crc32(message),
            compression="",
            data=message,
        )
    )
    for compression in ("", "zstd"):
        chunk = _record_bytes(
            Chunk(
                message_start_time=7,
                message_end_time=7,
                uncompressed_size=len(message),
                uncompressed_crc=0,
                compression=compression,
                data=message,
            )
        )
        header_end = 9 + 8 * 3 + 4 + 4 + len(compression) + 8  # opcode, length; times, size, crc; name; records length
        for cut in range(9, header_end):
            path = tmp_path / f"cut{compression}{cut}.mcap"
            path.write_bytes(good + first + chunk[:cut])
            scan, messages = scan_mcap(path)
            assert [m.data for m in messages] == [b"ab"], (compression, cut)
            assert scan.problems == [f"chunk cut at byte {len(good) + len(first)} (its header is incomplete)"], (
                compression,
                cut,
                scan.problems,
            )
        path = tmp_path / f"header{compression}.mcap"  # cut right after its header: no record of it read
        path.write_bytes(good + first + chunk[:header_end])
        scan, messages = scan_mcap(path)
        assert [m.data for m in messages] == [b"ab"]
        at = len(good) + len(first)
        assert scan.problems == [
            f"zstd-compressed chunk cut at byte {at}: its messages are lost"
            if compression
            else f"chunk cut at byte {at}: kept its 0 complete message(s)"
        ], scan.problems


def test_a_file_that_is_not_mcap_is_closed_at_once(tmp_path):
    """scan_mcap closes the file it rejects (dlo-bag-recover scans many files in one process)."""
    wrong = tmp_path / "wrong.mcap"
    wrong.write_bytes(b"not an mcap file at all")
    before = len(os.listdir("/proc/self/fd"))
    with pytest.raises(McapScanError) as raised:
        scan_mcap(wrong)
    assert len(os.listdir("/proc/self/fd")) == before, "the rejected file is still open"
    del raised


def _garble_the_first_chunk(data: bytearray, first: int, end: int) -> None:
    for k in range(first + 9 + 50, end):  # from inside the first schema record on: no definition parses
        data[k] = 0xFF


def test_the_summary_supplies_what_parses_and_only_a_footer_makes_it_trusted(tmp_path):
    """With the chunk holding every schema and channel unreadable, the summary section supplies them: each record
    that parses (a damaged schema record costs that schema only), also when the summary ends with a channel right
    before the footer (no statistics, indexes or summary offsets). A file without its footer (cut anywhere after
    DataEnd) has no trusted summary: nothing is read from it."""
    path = tmp_path / "a.mcap"
    write_example(path, chunk_size=250)
    data = bytearray(path.read_bytes())
    chunks = check_indexes(bytes(data))
    first = min(chunks)
    _garble_the_first_chunk(data, first, chunks[first][-1][2])
    footer = Footer.read(stream(record_at(bytes(data), len(data) - 37)[2]))
    schema_record = footer.summary_start
    assert record_at(bytes(data), schema_record)[0] == Opcode.SCHEMA
    damaged = bytearray(data)
    damaged[schema_record + 9 + 2 : schema_record + 9 + 6] = b"\xff\xff\xff\x7f"  # schema 1's name length: too long
    path.write_bytes(bytes(damaged))
    scan, messages = scan_mcap(path)
    list(messages)
    assert set(scan.schemas) == {2} and set(scan.channels) == {1, 2, 3}
    assert scan.channels[2].metadata == {"offered_qos_profiles": "- depth: 1"}
    # cut anywhere after DataEnd's start, before the footer is whole: no definition from the summary
    cut_path = tmp_path / "cut.mcap"
    for cut in range(footer.summary_start - 13, len(data)):
        cut_path.write_bytes(bytes(data[:cut]))
        scan, messages = scan_mcap(cut_path)
        list(messages)
        assert (scan.schemas, scan.channels) == ({}, {}), cut
    # a summary of schemas and channels only (another writer's choice): the last channel ends at the footer
    other = tmp_path / "other.mcap"
    with other.open("wb") as f:
        writer = Writer(
            f,
            chunk_size=10**6,
            compression=CompressionType.NONE,
            index_types=IndexType.NONE,
            use_statistics=False,
            use_summary_offsets=False,
        )
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("s", "ros2msg", b"float64 x\n")
        for k in range(3):
            writer.register_channel(f"/c{k}", "cdr", schema)
        for i in range(10):
            writer.add_message(1 + i % 3, log_time=i, data=b"x" * 20, publish_time=i)
        writer.finish()
    data = bytearray(other.read_bytes())
    footer = Footer.read(stream(record_at(bytes(data), len(data) - 37)[2]))
    last = records_at(bytes(data), footer.summary_start, len(data) - 37)[-1]
    assert last[1] == Opcode.CHANNEL and last[0] + last[2] == len(data) - 37
    chunk_start = next(o for o, op, _, _ in records_at(bytes(data), 8, footer.summary_start) if op == Opcode.CHUNK)
    _garble_the_first_chunk(data, chunk_start, chunk_start + record_at(bytes(data), chunk_start)[1])
    other.write_bytes(bytes(data))
    scan, messages = scan_mcap(other)
    assert list(messages) == [] and scan.problems
    assert {i: c.topic for i, c in scan.channels.items()} == {1: "/c0", 2: "/c1", 3: "/c2"} and set(scan.schemas) == {1}
