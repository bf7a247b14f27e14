"""Reading rosbag2 MCAP bags (no rclpy here): a bag or a directory of its rolled parts.

:func:`read_messages` yields ``(topic, type, timestamp, message)`` in timestamp order, decoded with
the definitions recorded in the bag; :func:`bag_parts` finds the parts. A damaged bag is one
:class:`~dlo_bag.errors.BagError` line that names the recovery command.
"""

from __future__ import annotations

import contextlib
import heapq
import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.interfaces import MessageDefinitionFormat
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from .errors import BagError, NotABagError, recover_hint
from .metadata import METADATA
from .typestore import make_typestore, register_type


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


class PartReaders:
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
    with PartReaders(bag) as readers:
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
