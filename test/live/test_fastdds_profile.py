"""config/fastdds_shm.xml sends Fast DDS's own warnings and errors to stderr, never into a tool's stdout.

A tool whose stdout a program reads (`roi-node param dump > p.yaml`) must not
get a Fast DDS log line in it. The fault is injected: a copy of the profile
whose loopback whitelist names an address this machine does not have makes
Fast DDS log an error when a participant starts. The same copy without the
profile's <log> section is the control: there the error lands on stdout.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from test.conftest import CONFIG, REPO
from test.dds.harness import next_domain, ros_env

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
