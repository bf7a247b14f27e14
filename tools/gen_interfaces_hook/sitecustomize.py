"""Records what every rclpy node of a process declares, for tools/gen_interfaces.py.

Active only when ``DLO_INTERFACES_DUMP`` names a directory (the generator puts this directory first
on PYTHONPATH of the graph it launches, so Python imports it at start-up as ``sitecustomize``).
It wraps ``rclpy.node.Node`` methods and appends one JSON line per node, publisher,
subscription, service, client, timer and declared parameter, and the topics of its first
``PUBLISHES_RECORDED`` publish calls (their order), to ``$DLO_INTERFACES_DUMP/<pid>.jsonl``:
the QoS exactly as the code requested it (depth and history, which DDS discovery does not
report), the resolved topic names (after remapping), timer periods [s] and parameter defaults.
It never changes what a method does or returns, and never raises.
"""

import os

_DUMP = os.environ.get("DLO_INTERFACES_DUMP")
PUBLISHES_RECORDED = 60


def _exe() -> str:
    """The executable (or ``python -m`` module) of this process; read late: runpy sets argv[0] after start-up."""
    import sys

    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "python"
    return name[:-3] if name.endswith(".py") else name


def _write(path: str, record: dict) -> None:
    import json

    try:
        with open(path, "a") as f:
            f.write(json.dumps(record, default=str) + "\n")
    except OSError:
        pass


def _type_name(cls) -> str:
    module = cls.__module__.split(".")  # e.g. sensor_msgs.msg._image
    return f"{module[0]}/{module[1]}/{cls.__name__}"


def _qos_record(qos) -> dict:
    import rclpy.qos

    if isinstance(qos, int):
        qos = rclpy.qos.QoSProfile(depth=qos)
    return {
        "history": qos.history.name.lower(),
        "depth": int(qos.depth),
        "reliability": qos.reliability.name.lower(),
        "durability": qos.durability.name.lower(),
    }


def _node_of(node) -> dict:
    return {"node": node.get_name(), "namespace": node.get_namespace(), "exe": _exe(), "pid": os.getpid()}


# what each wrapped Node method records: record(node, its result, its arguments...) -> the JSON line's fields


def _on_init(self, result, *args, **kwargs):
    return {"kind": "node"}


def _on_publisher(self, pub, msg_type, topic, qos_profile=10, **kwargs):
    return {"kind": "publisher", "topic": pub.topic_name, "type": _type_name(msg_type), **_qos_record(qos_profile)}


def _on_subscription(self, sub, msg_type, topic, callback, qos_profile=10, **kwargs):
    return {"kind": "subscription", "topic": sub.topic_name, "type": _type_name(msg_type), **_qos_record(qos_profile)}


def _on_service(self, service, srv_type, srv_name, callback, **kwargs):
    return {"kind": "service", "name": service.service_name, "type": _type_name(srv_type)}


def _on_client(self, client, srv_type, srv_name, **kwargs):
    return {"kind": "client", "name": getattr(client, "service_name", srv_name), "type": _type_name(srv_type)}


def _on_timer(self, timer, period, callback, *args, **kwargs):
    return {
        "kind": "timer",
        "period_s": timer.timer_period_ns / 1e9,
        "callback": getattr(callback, "__name__", type(callback).__name__),
    }


def _on_parameter(self, param, name, value=None, descriptor=None, *args, **kwargs):
    return {
        "kind": "parameter",
        "name": name,
        "default": value,
        "value": param.value,
        "description": getattr(descriptor, "description", "") or "",
    }


RECORDS = {
    "__init__": _on_init,
    "create_publisher": _on_publisher,
    "create_subscription": _on_subscription,
    "create_service": _on_service,
    "create_client": _on_client,
    "create_timer": _on_timer,
    "declare_parameter": _on_parameter,
}


def _wrap(cls, name: str, record, path: str) -> None:
    """``cls.name`` calls the original and then writes what ``record`` makes of the call (never raising)."""
    import functools

    method = getattr(cls, name)

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        result = method(self, *args, **kwargs)
        try:
            entry = record(self, result, *args, **kwargs)
            if entry is not None:
                _write(path, {**_node_of(self), **entry})
        except Exception:  # noqa: BLE001 - the hook never breaks a node
            pass
        return result

    setattr(cls, name, wrapper)


def _record_publishes(publisher_cls, path: str) -> None:
    """The topics of the process's first PUBLISHES_RECORDED publish calls, in order."""
    import functools

    publish = publisher_cls.publish
    published = [0]

    @functools.wraps(publish)
    def publish_wrapper(self, msg):
        if published[0] < PUBLISHES_RECORDED:  # the order of a process's first publishes (a few control steps)
            published[0] += 1
            _write(path, {"kind": "publish", "pid": os.getpid(), "seq": published[0], "topic": self.topic_name})
        return publish(self, msg)

    publisher_cls.publish = publish_wrapper


def _install(dump_dir: str) -> None:
    import rclpy.node
    import rclpy.publisher
    import rclpy.qos  # noqa: F401 - without it (or rclpy) the process runs unhooked

    path = os.path.join(dump_dir, f"{os.getpid()}.jsonl")
    _record_publishes(rclpy.publisher.Publisher, path)
    for name, record in RECORDS.items():
        _wrap(rclpy.node.Node, name, record, path)


if _DUMP:
    try:
        _install(_DUMP)
    except Exception:  # noqa: BLE001 - without rclpy (or on any error) the process runs unhooked
        pass
