"""dlo-bag-recover BAG: make a killed or cut-short recording a complete, readable bag again.

Like ``ros2 bag reindex`` + ``mcap recover``: every complete message of the bag's ``.mcap`` (also
of a file cut in the middle of a chunk) is copied into a new, fully indexed ``.mcap`` with the
recorded schemas, and ``metadata.yaml`` is rebuilt from the MCAP records (topics, types, counts,
offered QoS, RIHS01 type hashes). The original file is kept as ``<name>.mcap.damaged`` unless
``--delete-original`` (or the recovered bag goes to ``--output DIR``). A bag that reads completely
is left alone. Works on a bag directory or a directory of rolled parts (``split_episodes``).

Exit status (the same table for every bag tool, ``dlo_bag.errors``): 0 recovered (or nothing to
do), 1 a part could not be recovered, 2 bad option, no such path or not a bag.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import os
import shutil
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from dlo_common.console import console_main
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

from .errors import EXIT_BAD_BAG, EXIT_OK, EXIT_USAGE, BagError, NotABagError
from .mcap_file import WRITER_NAME, McapScanError, scan_mcap
from .metadata import METADATA, write_metadata
from .reader import read_messages
from .writer import RESERVE_FILE, BagWriteError, BagWriter, TopicSpec

DAMAGED_SUFFIX = ".damaged"
WORK_DIR = ".dlo_recovering"


@dataclass
class RecoverReport:
    """What happened to one bag directory."""

    part: Path
    action: str  # "intact", "recovered", "failed"
    messages: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    discarded_bytes: int = 0
    problems: list[str] = field(default_factory=list)
    original: Path | None = None
    output: Path | None = None
    error: str = ""

    def line(self) -> str:
        if self.action == "intact":
            return f"{self.part}: complete and readable ({self.messages} messages); nothing to recover"
        if self.action == "failed":
            return f"{self.part}: cannot be recovered: {self.error}"
        cut = f"; the last {self.discarded_bytes} byte(s), an incomplete record, discarded" if self.discarded_bytes else ""
        kept = f"; original kept as {self.original.name}" if self.original is not None else ""
        where = f" into {self.output}" if self.output is not None and self.output != self.part else ""
        return (
            f"{self.part}: recovered {self.messages} messages on {len(self.topics)} topics{where} ({METADATA} rebuilt{cut}{kept})"
        )


def _hash_from_definition(msgtype: str, encoding: str, text: str) -> str:
    """RIHS01 hash of ``msgtype`` computed from its recorded definition ('' if impossible)."""
    try:
        store = get_typestore(Stores.EMPTY)
        if encoding == "ros2msg":
            store.register(get_types_from_msg(text, msgtype))
        else:
            store.register(get_types_from_idl(text))
        return store.hash_rihs01(msgtype)
    except Exception:  # noqa: BLE001 - an unparsable definition: no hash rather than no bag
        return ""


def _topic_spec(scan, channel_id: int) -> TopicSpec | None:
    """The TopicSpec of a scanned channel (its schema, QoS and hash), None without a schema."""
    channel = scan.channels.get(channel_id)
    if channel is None:
        return None
    schema = scan.schemas.get(channel.schema_id)
    if schema is None:
        scan.problems.append(f"channel {channel.topic} has no schema: its messages are skipped")
        return None
    text = schema.data.decode("utf-8", errors="replace")
    try:
        qos = parse_qos(channel.metadata.get("offered_qos_profiles", "") or [])
    except Exception:  # noqa: BLE001 - unreadable QoS: record without it
        qos = []
    digest = channel.metadata.get("topic_type_hash") or _hash_from_definition(schema.name, schema.encoding, text)
    return TopicSpec(channel.topic, schema.name, list(qos), digest, text)


def bag_dirs(path: Path) -> list[Path]:
    """The bag directories under ``path``: itself, or its parts (sub-directories with .mcap)."""
    if (path / METADATA).is_file() or any(path.glob("*.mcap")):
        return [path]
    parts = sorted(p for p in path.iterdir() if p.is_dir() and any(p.glob("*.mcap")))
    if not parts:
        raise NotABagError(f"'{path}' holds no .mcap file (nor parts with one): nothing to recover")
    return parts


def _is_intact(part: Path) -> int | None:
    """Number of messages when the bag reads completely, else None."""
    if not (part / METADATA).is_file():
        return None
    try:
        return sum(1 for _ in read_messages(part, raw=True))
    except BagError:
        return None


def _the_mcap(part: Path) -> Path | RecoverReport:
    """The one .mcap file of ``part``, or the failed report when it has none or several."""
    mcaps = sorted(part.glob("*.mcap"))
    if not mcaps:
        return RecoverReport(part, "failed", error="no .mcap file in it")
    if len(mcaps) > 1:
        return RecoverReport(
            part, "failed", error=f"{len(mcaps)} .mcap files; recover a bag of one file (copy each into its own directory)"
        )
    return mcaps[0]


def _write_salvage(scan, messages, work: Path, source: Path) -> tuple[Counter, dict[int, TopicSpec | None]]:
    """Write every salvaged message of ``scan`` into a new bag at ``work``: (messages per topic, the topic spec
    of each channel). Raises BagError/OSError when the bag cannot be written."""
    writer = BagWriter(work, get_typestore(Stores.EMPTY), reserve=False)
    specs: dict[int, TopicSpec | None] = {}
    counts: Counter = Counter()

    def spec_of(channel_id: int) -> TopicSpec | None:
        if channel_id not in specs:
            specs[channel_id] = _topic_spec(scan, channel_id)
            if specs[channel_id] is not None:
                writer.add_topic_spec(specs[channel_id])
        return specs[channel_id]

    for message in messages:
        spec = spec_of(message.channel_id)
        if spec is not None:
            writer.write(spec.topic, message.data, message.log_time)
            counts[spec.topic] += 1
    for channel_id in scan.channels:  # topics without messages are listed too
        spec_of(channel_id)
    old = scan.metadata.get("rosbag2", {}).get("serialized_metadata")
    with contextlib.suppress(Exception):
        writer.custom_data.update((yaml.safe_load(old) or {}).get("custom_data") or {})
    writer.custom_data[f"{WRITER_NAME}.recovered"] = (
        f"{datetime.datetime.now():%Y-%m-%d %H:%M:%S} by dlo-bag-recover from {source.name}: "
        f"{sum(counts.values())} messages, {scan.discarded} bytes discarded"
    )
    writer.close()
    return counts, specs


def _replace_in_place(part: Path, source: Path, work: Path, report: RecoverReport, keep_original: bool) -> None:
    """In place: the recovered .mcap takes the original's name, metadata.yaml is rewritten for it."""
    recovered = work / f"{work.name}.mcap"
    if keep_original:
        report.original = source.with_name(source.name + DAMAGED_SUFFIX)
        os.replace(source, report.original)
    else:
        source.unlink()
    os.replace(recovered, source)
    info = yaml.safe_load((work / METADATA).read_text())["rosbag2_bagfile_information"]
    info["relative_file_paths"] = [source.name]
    for entry in info.get("files", []):
        entry["path"] = source.name
    write_metadata(part, info)
    shutil.rmtree(part / WORK_DIR, ignore_errors=True)


def recover_part(part: Path, *, output: Path | None = None, keep_original: bool = True) -> RecoverReport:
    """Recover one bag directory (see the module doc)."""
    (part / RESERVE_FILE).unlink(missing_ok=True)
    intact = _is_intact(part)
    if intact is not None and output is None:
        return RecoverReport(part, "intact", messages=intact)
    source = _the_mcap(part)
    if isinstance(source, RecoverReport):
        return source
    try:
        scan, messages = scan_mcap(source)
    except (McapScanError, OSError) as err:
        return RecoverReport(part, "failed", error=str(err))
    report = RecoverReport(part, "recovered", output=output or part)
    work = output if output is not None else part / WORK_DIR / part.name
    if output is None and work.parent.exists():
        shutil.rmtree(work.parent)
    try:
        counts, specs = _write_salvage(scan, messages, work, source)
    except (BagError, OSError) as err:
        if output is None:
            shutil.rmtree(part / WORK_DIR, ignore_errors=True)
        cause = err.cause if isinstance(err, BagWriteError) else str(err)
        return RecoverReport(
            part, "failed", error=f"cannot write the recovered bag: {cause} (free some space, or use --output DIR elsewhere)"
        )
    if not counts and not any(s is not None for s in specs.values()):
        if output is None:
            shutil.rmtree(part / WORK_DIR, ignore_errors=True)
        else:
            shutil.rmtree(output, ignore_errors=True)
        return RecoverReport(
            part, "failed", error=f"{source.name} holds no complete record to salvage", problems=list(scan.problems)
        )
    report.messages = sum(counts.values())
    report.topics = dict(counts)
    report.discarded_bytes = scan.discarded
    report.problems = list(scan.problems)
    if output is None:
        _replace_in_place(part, source, work, report, keep_original)
    return report


def recover_bag(
    path: str | os.PathLike, *, output: str | os.PathLike | None = None, keep_original: bool = True
) -> list[RecoverReport]:
    """Recover a bag directory or a directory of parts; one report per bag directory."""
    path = Path(path)
    if not path.is_dir():
        raise NotABagError(
            f"'{path}' is not a directory (give the bag directory, not a file)" if path.exists() else f"'{path}' does not exist"
        )
    parts = bag_dirs(path)
    out = Path(output) if output is not None else None
    if out is not None and out.exists():
        raise NotABagError(f"--output '{out}' exists already; choose a new directory")
    reports = []
    for part in parts:
        target = None
        if out is not None:
            target = out if parts == [path] else out / part.name
        reports.append(recover_part(part, output=target, keep_original=keep_original))
    return reports


@console_main("dlo-bag-recover")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="dlo-bag-recover",
        description="Recover a rosbag2 MCAP bag whose recorder was killed (no metadata.yaml) or whose "
        ".mcap was cut short: salvage every complete message into a valid, indexed bag "
        "and rebuild metadata.yaml (like 'ros2 bag reindex' + 'mcap recover').",
    )
    parser.add_argument("bag", help="bag directory (or a directory of rolled parts)")
    parser.add_argument("--output", "-o", help="write the recovered bag here and leave BAG untouched")
    parser.add_argument(
        "--delete-original",
        action="store_true",
        help="in place: delete the damaged .mcap instead of keeping it as *.mcap.damaged",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="also list what was damaged")
    args = parser.parse_args(argv)
    try:
        reports = recover_bag(args.bag, output=args.output, keep_original=not args.delete_original)
    except (BagError, OSError) as err:
        print(f"dlo-bag-recover: error: {err}", file=sys.stderr)
        return EXIT_USAGE if isinstance(err, NotABagError) else EXIT_BAD_BAG
    for report in reports:
        print(report.line())
        if args.verbose:
            for problem in report.problems:
                print(f"  {problem}")
    return EXIT_BAD_BAG if any(r.action == "failed" for r in reports) else EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
