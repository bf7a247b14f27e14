"""dlo_common.testing.reserve_domains: a ROS domain a test uses is used by nothing else on the machine
(another test process, a pytest-xdist worker, launch_graph.sh, any DDS participant)."""

import socket
import subprocess
import sys

import pytest

from dlo_common import testing


def reserve_in_another_process(first: int, last: int, span: int = 1) -> str:
    """What reserve_domains gives a second process ('none' when nothing is free)."""
    code = ("from dlo_common import testing\n"
            f"try:\n    print(testing.reserve_domains({span}, {first}, {last}))\n"
            "except RuntimeError:\n    print('none')\n")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          check=True).stdout.strip()


def test_a_reserved_domain_is_refused_to_another_process_until_released():
    domain = testing.reserve_domains()
    try:
        assert testing.TEST_DOMAINS[0] <= domain <= testing.TEST_DOMAINS[1]
        assert reserve_in_another_process(domain, domain) == "none"
        neighbours = reserve_in_another_process(domain - 1, domain + 1)
        assert neighbours in (str(domain - 1), str(domain + 1), "none")  # never the held one
        with pytest.raises(RuntimeError, match="no 1 free ROS domain"):
            testing.reserve_domains(1, domain, domain)  # this process holds it: not given twice either
    finally:
        testing.release_domains(domain)
    assert reserve_in_another_process(domain, domain) == str(domain)  # released: free again


def test_a_span_is_consecutive_free_domains_all_held():
    first = testing.reserve_domains(3)
    try:
        for domain in (first, first + 1, first + 2):
            assert reserve_in_another_process(domain, domain) == "none", domain
    finally:
        testing.release_domains(first, 3)
    assert reserve_in_another_process(first + 1, first + 1) == str(first + 1)


def test_a_domain_with_a_participant_on_its_ports_is_skipped():
    """A DDS participant of another program (not a dlo-vitac lock) on a domain: its ports are bound."""
    with testing.reserved_domain() as free:
        pass  # a domain nothing else held a moment ago
    for offset in (0, 249):  # the first and the last port of the domain's range
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(("127.0.0.1", 7400 + 250 * free + offset))
            assert testing.domain_busy(free)
            assert reserve_in_another_process(free, free) == "none"
        finally:
            sock.close()
    assert not testing.domain_busy(free)
    assert reserve_in_another_process(free, free) == str(free)


def test_the_context_manager_releases_and_isolated_env_reserves():
    with testing.reserved_domain(2) as domain:
        assert reserve_in_another_process(domain + 1, domain + 1) == "none"
    assert reserve_in_another_process(domain, domain + 1, span=2) == str(domain)
    env = testing.isolated_env({"PATH": "/usr/bin", "ROS_DOMAIN_ID": "0", "ROS_LOCALHOST_ONLY": "1"})
    domain = int(env["ROS_DOMAIN_ID"])
    try:
        assert domain != 0 and reserve_in_another_process(domain, domain) == "none"  # held for this process
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and "ROS_LOCALHOST_ONLY" not in env
    finally:
        testing.release_domains(domain)
