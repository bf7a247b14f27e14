"""The bag library's names in one place, for the callers that import them from here.

The library is one module per concern (as rosbag2's): :mod:`dlo_bag.typestore`, :mod:`dlo_bag.qos`,
:mod:`dlo_bag.metadata`, :mod:`dlo_bag.writer`, :mod:`dlo_bag.reader`, :mod:`dlo_bag.info`, with the
errors and the tools' exit codes in :mod:`dlo_bag.errors`; new code imports from those.
"""

from .errors import EXIT_BAD_BAG, EXIT_NO_TASK_STATE, EXIT_OK, EXIT_USAGE, RECOVER_COMMAND, BagError, NotABagError, recover_hint
from .info import BagInfo, TopicInfo, bag_info, format_info
from .metadata import BAG_VERSION, METADATA, bag_metadata, write_metadata
from .qos import qos_from_profile, qos_yaml, subscription_qos
from .reader import BagMessage, PartReaders, bag_parts, read_messages
from .typestore import (
    DEFAULT_PACKAGES,
    ament_prefixes,
    interface_file,
    make_typestore,
    message_definition,
    register_package,
    register_type,
    type_hash,
)
from .writer import RESERVE_FILE, BagWriteError, BagWriter, TopicSpec, os_error_cause

__all__ = [
    "BAG_VERSION",
    "DEFAULT_PACKAGES",
    "EXIT_BAD_BAG",
    "EXIT_NO_TASK_STATE",
    "EXIT_OK",
    "EXIT_USAGE",
    "METADATA",
    "RECOVER_COMMAND",
    "RESERVE_FILE",
    "BagError",
    "BagInfo",
    "BagMessage",
    "BagWriteError",
    "BagWriter",
    "NotABagError",
    "PartReaders",
    "TopicInfo",
    "TopicSpec",
    "ament_prefixes",
    "bag_info",
    "bag_metadata",
    "bag_parts",
    "format_info",
    "interface_file",
    "make_typestore",
    "message_definition",
    "os_error_cause",
    "qos_from_profile",
    "qos_yaml",
    "read_messages",
    "recover_hint",
    "register_package",
    "register_type",
    "subscription_qos",
    "type_hash",
    "write_metadata",
]
