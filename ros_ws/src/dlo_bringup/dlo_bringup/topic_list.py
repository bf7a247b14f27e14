"""topic_list: the topics on this ROS domain, one a line, as ``ros2 topic list`` prints them; for the wheels,
which have no ``ros2`` command (the launcher suggests it: ``ROS_DOMAIN_ID=N scripts/ros2run dlo_bringup
topic_list``).

Discovery takes a while (up to seconds on a loaded machine): it waits at least ``--wait`` s (default 4) and
until the list has not changed for 1 s (at most 15 s), then prints it.
"""

from __future__ import annotations

import argparse
import sys
import time

WAIT = 4.0  # s at least: a participant can take 2.5 s to be discovered (Fast DDS, localhost, a loaded machine)
SETTLE = 1.0  # s without a change in the list before it is printed
LIMIT = 15.0  # s at most


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="topic_list", description=__doc__.split("\n\n")[0])
    parser.add_argument("-t", "--show-types", action="store_true", help="also each topic's type(s)")
    parser.add_argument("--wait", type=float, default=WAIT, help=f"seconds to wait at least (default {WAIT:g})")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    import rclpy
    from dlo_common.node_main import shut_down
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C: KeyboardInterrupt, one line below
    node = None
    try:
        node = rclpy.create_node("topic_list")
        start = changed = time.monotonic()
        topics = []
        while True:
            now = time.monotonic()
            seen = sorted(node.get_topic_names_and_types())
            if seen != topics:
                topics, changed = seen, now
            if now - start >= LIMIT or (now - start >= args.wait and now - changed >= SETTLE):
                break
            time.sleep(0.1)
    except KeyboardInterrupt:
        print("topic_list: interrupted", file=sys.stderr)
        return 130
    finally:
        shut_down(node)
    for name, types in topics:
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
