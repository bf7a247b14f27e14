"""dlo-bag-info BAG: topics, types, counts and duration of a bag, like ``ros2 bag info``.

Exit status (the same table for every bag tool, ``dlo_bag.errors``): 0 printed, 1 the bag is
damaged (run dlo-bag-recover), 2 bad option, no such path or not a bag.
"""

from __future__ import annotations

import argparse
import json
import sys

from dlo_common.console import console_main

from .errors import EXIT_BAD_BAG, EXIT_USAGE, BagError, NotABagError
from .info import bag_info, format_info


@console_main("dlo-bag-info")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="dlo-bag-info",
        description="Print the topics, types, message counts and duration of a rosbag2 bag "
        "(or of a directory of rolled bag parts).",
        epilog="exit status: 0 printed, 1 damaged bag (run dlo-bag-recover), 2 bad option, no such path or not a bag",
    )
    parser.add_argument("bag", help="bag directory (with metadata.yaml) or directory of parts")
    parser.add_argument("-v", "--verbose", action="store_true", help="also print type hashes, offered QoS and custom data")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    args = parser.parse_args(argv)
    try:
        info = bag_info(args.bag)
    except (BagError, OSError) as err:
        print(f"dlo-bag-info: error: {err}", file=sys.stderr)
        return EXIT_USAGE if isinstance(err, NotABagError) else EXIT_BAD_BAG
    if args.json:
        print(
            json.dumps(
                {
                    "path": str(info.path),
                    "parts": [str(p) for p in info.parts],
                    "files": [str(f) for f in info.files],
                    "size": info.size,
                    "start_ns": info.start_ns,
                    "end_ns": info.end_ns,
                    "duration_s": info.duration_ns / 1e9,
                    "message_count": info.message_count,
                    "topics": {
                        name: {"type": t.msgtype, "count": t.count, "type_hash": t.rihs01}
                        for name, t in sorted(info.topics.items())
                    },
                }
            )
        )
    else:
        print(format_info(info, verbose=args.verbose))
    return 0


if __name__ == "__main__":
    sys.exit(main())
