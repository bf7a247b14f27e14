"""The type store of the bags: the ROS 2 Jazzy types plus the project's interfaces (no rclpy here).

:func:`make_typestore` registers dlo_msgs from their installed ``.msg`` text found through
``AMENT_PREFIX_PATH``; any other installed type is registered on demand (:func:`register_type`).
:func:`message_definition` is the one source of the schema text (ros2msg) and the RIHS01 hash of
the recorder's bags and of the Foxglove bridge's channels.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from .errors import BagError

DEFAULT_PACKAGES = ("dlo_msgs",)


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
