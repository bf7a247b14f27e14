"""Recorder logic without rclpy: which topics to record, counting, rolling bags per N episodes.

The recorder node feeds it topics it discovers (:meth:`Recorder.add_topic`) and every raw
message it receives (:meth:`Recorder.on_message`), calls :meth:`Recorder.flush` regularly (what
was received reaches the disk: a killed recorder loses at most the time since the last flush),
and :meth:`Recorder.close` finalises the bag and returns the received/written counts
(dropped = received - written, must be 0). A write error (disk full, I/O, permission) is fatal:
:attr:`Recorder.failure` names the cause, nothing more is written, and :meth:`Recorder.close`
still closes the bag with everything written before the error.

What drives the run (the policy node's latched ``/dlo/policy/info``, JSON) is recorded like every topic and
also copied into the bag's metadata (``custom_data`` key :data:`POLICY_KEY`), so that every part of a split
recording says it, not only the first (where the latched message lands).
"""

from __future__ import annotations

import datetime
import os
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from dlo_common.topics import topic as topic_record
from rosbags.interfaces import Qos
from rosbags.typesys.store import Typestore

from .errors import BagError
from .mcap_file import WRITER_NAME
from .typestore import make_typestore
from .writer import BagWriteError, BagWriter, TopicSpec

TASK_TOPIC = topic_record("task").name  # the topic that marks episodes (dlo_common.topics)
TASK_TYPE = topic_record("task").type
POLICY_TOPIC = topic_record("policy_info").name  # what drives the run (dlo_policy.policy_node.policy_record)
POLICY_TYPE = topic_record("policy_info").type
POLICY_KEY = f"{WRITER_NAME}.policy"  # its copy in the bag's metadata (custom_data)


def default_output(root: str | os.PathLike = "bags") -> Path:
    """``bags/rosbag2_YYYY_MM_DD-HH_MM_SS`` (relative to the working directory)."""
    stamp = datetime.datetime.now().strftime("%Y_%m_%d-%H_%M_%S")
    return Path(root) / f"rosbag2_{stamp}"


def topic_selected(topic: str, namespace: str = "/dlo", *, clock: bool = False, extra: Iterable[str] = ()) -> bool:
    """True for ``namespace`` and topics under it, ``/clock`` if asked, and ``extra`` topics."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else "/"
    if ns == "/" or topic == ns or topic.startswith(ns + "/"):
        return True
    if clock and topic == "/clock":
        return True
    return topic in set(extra)


@dataclass
class RecordSummary:
    """What a recording received and wrote, per topic."""

    path: Path
    parts: list[Path]
    received: dict[str, int]
    written: dict[str, int]
    errors: int = 0
    last_error: str = ""
    lost: dict[str, int] | None = None  # messages the middleware reported lost, per topic
    failure: str = ""  # why the recording failed (e.g. 'no space left on device'); "" = it did not
    received_at_failure: int = 0  # messages received up to and including the one that failed
    complete: bool = True  # every part of the bag is closed with its metadata.yaml

    @property
    def total_received(self) -> int:
        return sum(self.received.values())

    @property
    def total_written(self) -> int:
        return sum(self.written.values())

    @property
    def total_lost(self) -> int:
        return sum((self.lost or {}).values())

    @property
    def dropped(self) -> int:
        """Received but not written, plus what the middleware reported lost before delivery."""
        return self.total_received - self.total_written + self.total_lost

    def to_dict(self) -> dict:
        """JSON-ready counts (e.g. for benchmarks: ``dropped`` must be 0)."""
        return {
            "path": str(self.path),
            "parts": [str(p) for p in self.parts],
            "received": self.total_received,
            "written": self.total_written,
            "lost": self.total_lost,
            "dropped": self.dropped,
            "errors": self.errors,
            "failure": self.failure,
            "received_at_failure": self.received_at_failure,
            "complete": self.complete,
            "topics": {
                t: {"received": self.received.get(t, 0), "written": self.written.get(t, 0), "lost": (self.lost or {}).get(t, 0)}
                for t in sorted(set(self.received) | set(self.written))
            },
        }

    def lines(self) -> list[str]:
        out = [
            f"bag {self.path} ({len(self.parts)} part{'s' if len(self.parts) != 1 else ''}): "
            f"received {self.total_received}, written {self.total_written}, "
            f"dropped {self.dropped}"
        ]
        lost = self.lost or {}
        for topic in sorted(set(self.received) | set(self.written)):
            out.append(
                f"  {topic}: received {self.received.get(topic, 0)}, "
                f"written {self.written.get(topic, 0)}" + (f", lost before delivery {lost[topic]}" if lost.get(topic) else "")
            )
        if self.errors:
            out.append(f"  {self.errors} write errors; last: {self.last_error}")
        if self.failure:
            out.append(
                f"  after the write error ({self.failure}) the bag was closed with the "
                f"{self.total_written} message(s) written, of {self.received_at_failure} "
                "received until the error" + ("" if self.complete else f"; it needs recovering: dlo-bag-recover {self.path}")
            )
        return out


class Recorder:
    """Writes every message it is given to a bag; rolls to a new bag every N episodes.

    ``split_episodes=0``: one bag per run at ``output``. ``split_episodes=N``: ``output`` is a
    directory of complete bags, a new one started when a ``TaskState`` on ``task_topic`` begins
    episode k*N (messages that arrive later but belong to the previous step land in the new part).
    """

    def __init__(
        self,
        output: str | os.PathLike,
        *,
        typestore: Typestore | None = None,
        split_episodes: int = 0,
        task_topic: str = TASK_TOPIC,
        fsync: bool = True,
    ) -> None:
        if split_episodes < 0:
            raise ValueError(f"split_episodes must be >= 0, got {split_episodes}")
        self.typestore = typestore if typestore is not None else make_typestore()
        self.split_episodes = split_episodes
        self.task_topic = task_topic
        self.writer = BagWriter(output, self.typestore, split=split_episodes > 0, fsync=fsync)
        self.writer.open()
        self.received: Counter[str] = Counter()
        self.lost: Counter[str] = Counter()
        self.errors = 0
        self.last_error = ""
        self.failure = ""
        self.received_at_failure = 0
        self._chunk: int | None = None
        self._episodes: set[int] = set()
        self._summary: RecordSummary | None = None

    @property
    def path(self) -> Path:
        return self.writer.path

    @property
    def topics(self) -> dict[str, TopicSpec]:
        return self.writer.topics

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> TopicSpec:
        """Start recording ``topic`` (raises BagError for a type that cannot be found)."""
        return self.writer.add_topic(topic, msgtype, qos)

    def _episode_boundary(self, data: bytes) -> None:
        msg = self.typestore.deserialize_cdr(data, TASK_TYPE)
        episode = int(msg.episode)
        chunk = episode // self.split_episodes
        if self._chunk is not None and chunk != self._chunk:
            self.writer.roll()
            self._episodes = set()
        self._chunk = chunk
        self._episodes.add(episode)
        self.writer.custom_data[f"{WRITER_NAME}.episodes"] = f"{min(self._episodes)}-{max(self._episodes)}"

    def _note_policy(self, data: bytes) -> None:
        """Copy the policy record (a std_msgs/String) into the bag's metadata; a message that does not decode is
        recorded all the same, without the copy."""
        try:
            self.writer.custom_data[POLICY_KEY] = str(self.typestore.deserialize_cdr(data, POLICY_TYPE).data)
        except Exception:  # noqa: BLE001 - the message itself is still written
            pass

    def _failed(self, err: BagWriteError) -> str:
        if not self.failure:
            self.errors += 1
            self.last_error = str(err)
            self.failure = err.cause
            self.received_at_failure = sum(self.received.values())
        return self.last_error

    def on_message(self, topic: str, data: bytes | memoryview, timestamp: int) -> str | None:
        """Record one raw message; returns an error text when it could not be written.

        After a write error (:attr:`failure` set) messages are only counted, not written.
        """
        self.received[topic] += 1
        if self.failure:
            return self.last_error
        try:
            if self.split_episodes and topic == self.task_topic:
                self._episode_boundary(bytes(data))
            if topic.endswith(POLICY_TOPIC):  # /dlo/policy/info, also under a namespace (/NS/dlo/policy/info)
                self._note_policy(bytes(data))
            self.writer.write(topic, data, timestamp)
        except BagWriteError as err:
            return self._failed(err)
        except Exception as err:  # noqa: BLE001 - one bad message: counted as dropped, reported
            self.errors += 1
            self.last_error = f"{topic}: {type(err).__name__}: {err}"
            return self.last_error
        return None

    def flush(self) -> str | None:
        """Put everything received so far on disk; returns the error text of a write failure."""
        if self.failure:
            return self.last_error
        try:
            self.writer.flush()
        except BagWriteError as err:
            return self._failed(err)
        return None

    def on_lost(self, topic: str, count: int) -> None:
        """The middleware reports ``count`` messages of ``topic`` lost before delivery."""
        self.lost[topic] += count

    def close(self) -> RecordSummary:
        """Finalise the bag (metadata.yaml) and return the counts; idempotent."""
        if self._summary is None:
            try:
                self.writer.close()
            except BagWriteError as err:
                self._failed(err)
                if err is not self.writer.failed:  # closing failed too: say so, keep the first cause
                    self.last_error = str(err)
            except BagError as err:
                self.errors += 1
                self.last_error = str(err)
            finally:
                self._summary = RecordSummary(
                    self.writer.path,
                    list(self.writer.parts),
                    dict(self.received),
                    dict(self.writer.counts),
                    self.errors,
                    self.last_error,
                    dict(self.lost),
                    self.failure,
                    self.received_at_failure,
                    self.writer.complete,
                )
        return self._summary
