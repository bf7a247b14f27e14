"""A bag directory's ``metadata.yaml`` (rosbag2 version 9): its content and its atomic write."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import yaml
from rosbags.rosbag2.metadata import dump_qos_v9

if TYPE_CHECKING:
    from .writer import TopicSpec

BAG_VERSION = 9
METADATA = "metadata.yaml"


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
