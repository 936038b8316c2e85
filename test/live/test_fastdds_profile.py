"""config/fastdds_shm.xml sends Fast DDS's own warnings and errors to stderr, never into a tool's stdout; a
shared-memory port held by another process costs one benign error line there.

A tool whose stdout a program reads (`roi-node param dump > p.yaml`) must not
get a Fast DDS log line in it. The fault is injected: a copy of the profile
whose loopback whitelist names an address this machine does not have makes
Fast DDS log an error when a participant starts. The same copy without the
profile's <log> section is the control: there the error lands on stdout.
"""

from __future__ import annotations

import fcntl
import os
import re
import subprocess
import sys
from contextlib import suppress
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from test.dds.harness import PORT_BASE, PORTS_PER_DOMAIN, next_domain, purge_domain_ports, ros_env, tool_lines, wait_until
from test.support.paths import CONFIG, REPO

PARTICIPANT = "import rclpy; rclpy.init(); node = rclpy.create_node('profile_probe'); print('started'); node.destroy_node()"
FILTERED_OUT = "All whitelist interfaces were filtered out"


def start_participant(profile: Path) -> subprocess.CompletedProcess[str]:
    env = {**ros_env(next_domain()), "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)}
    return subprocess.run([sys.executable, "-c", PARTICIPANT], cwd=REPO, env=env, capture_output=True, text=True, timeout=60)


@pytest.mark.dds
def test_fast_dds_errors_go_to_stderr_and_stdout_holds_only_the_programs_output(tmp_path: Path) -> None:
    profile = (CONFIG / "fastdds_shm.xml").read_text()
    broken = profile.replace("<address>127.0.0.1</address>", "<address>10.254.254.254</address>")
    assert broken != profile
    (tmp_path / "broken.xml").write_text(broken)
    (tmp_path / "control.xml").write_text(re.sub(r"<log>.*</log>", "", broken, flags=re.S))

    run = start_participant(tmp_path / "broken.xml")
    assert run.returncode == 0, run.stderr
    assert run.stdout == "started\n"
    assert FILTERED_OUT in run.stderr

    control = start_participant(tmp_path / "control.xml")
    assert control.returncode == 0, control.stderr
    assert FILTERED_OUT in control.stdout  # Fast DDS's default: its log on stdout


LISTENER = """
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node('port_probe')
got = []
node.create_subscription(String, 'probe', got.append, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
print('subscribed', flush=True)
deadline = time.monotonic() + 30
while not got and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print('received' if got else 'nothing received', flush=True)
"""


@pytest.mark.dds
def test_a_shared_memory_port_held_by_another_process_costs_one_benign_error_line(tmp_path: Path) -> None:
    """The fault is injected: the lock file of the first shared-memory port a new participant of the domain tries is
    held (flock) here, as a live but stopped or starved process holds it. Fast DDS logs one "Failed init_port"
    error, takes the next port and the participant works: a message published to it arrives. `tool_lines` drops
    exactly that line from a tool's stderr."""
    domain = next_domain()
    port = PORT_BASE + PORTS_PER_DOMAIN * domain + 11  # the first participant's user-data unicast port
    lock_file = Path(f"/dev/shm/fastrtps_port{port}_el")
    fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        listener = subprocess.Popen([sys.executable, "-c", LISTENER], cwd=REPO, env=ros_env(domain), stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
        try:
            assert listener.stdout is not None and listener.stdout.readline() == "subscribed\n"
            context = Context()
            rclpy.init(context=context, domain_id=domain)
            try:
                node = Node("port_probe_talker", context=context)
                publisher = node.create_publisher(String, "probe", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
                assert wait_until(lambda: publisher.get_subscription_count() >= 1, 30.0)
                listener_done = False
                while not listener_done:  # it exits once it took one (a reliable message sent before its reader matched is lost)
                    publisher.publish(String(data="hello"))
                    with suppress(subprocess.TimeoutExpired):
                        listener_done = listener.wait(timeout=0.1) is not None
            finally:
                rclpy.shutdown(context=context)
            out, err = listener.communicate(timeout=30)
        finally:
            listener.kill()
    finally:
        os.close(fd)
        lock_file.unlink(missing_ok=True)
    assert listener.returncode == 0 and out == "received\n", err
    assert f"Failed init_port fastrtps_port{port}: open_and_lock_file failed" in err
    assert tool_lines(err) == [], err


def test_a_domains_ports_that_no_live_process_holds_are_purged_before_it_is_reused(tmp_path: Path) -> None:
    domain = 150
    first = PORT_BASE + PORTS_PER_DOMAIN * domain
    held, dead, unlocked, other = first + 11, first + 13, first + 15, first + PORTS_PER_DOMAIN + 11
    for port in (held, dead, other):
        for suffix in ("", "_el"):
            (tmp_path / f"fastrtps_port{port}{suffix}").write_bytes(b"\x02\x00\x00\x00")
        (tmp_path / f"sem.fastrtps_port{port}_mutex").write_bytes(b"")
    (tmp_path / f"fastrtps_port{unlocked}").write_bytes(b"")  # created by a writer, or its creator died before the lock
    fd = os.open(tmp_path / f"fastrtps_port{held}_el", os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a live listener holds its port
        removed = purge_domain_ports(domain, tmp_path)
    finally:
        os.close(fd)
    assert sorted(removed) == [f"fastrtps_port{dead}", f"fastrtps_port{unlocked}"]
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted([f"fastrtps_port{held}", f"fastrtps_port{held}_el", f"sem.fastrtps_port{held}_mutex",
                           f"fastrtps_port{other}", f"fastrtps_port{other}_el", f"sem.fastrtps_port{other}_mutex"])
