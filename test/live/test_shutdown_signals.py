"""A second SIGINT/SIGTERM while a node is closing is ignored: the close finishes and the process exits 0.

docs/live-node.md, "Status line, shutdown and summary". The child process runs
`spin_node` (what `roi-node run` runs) on a real rclpy node whose `close` takes
a second signal itself, at the moment the node's summary would be logged; with
rclpy's or Python's default handlers back in place that signal would end the
process (KeyboardInterrupt, exit 130) before the close is done. Each test runs
on every executor `spin_node` offers (the EventsExecutor installs signal
handlers of its own: spin.py must put its handlers back, and keep them until
the node is closed).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from roi_node.live.spin import ExecutorKind
from test.dds.harness import next_domain, ros_env
from test.support.paths import REPO

TIMEOUT_S = 120.0
CHILD = textwrap.dedent(
    """
    import signal
    import sys

    from rclpy.node import Node

    from roi_node.live.spin import ExecutorKind, spin_node


    class SlowToClose(Node):
        def __init__(self) -> None:
            super().__init__("slow_to_close")
            print("up", flush=True)

        def close(self) -> None:
            print("closing", flush=True)
            signal.raise_signal(signal.SIGINT)  # its Python handler runs before the next line
            print("closed", flush=True)


    sys.exit(spin_node(SlowToClose, executor=ExecutorKind(sys.argv[1])))
    """
)


@pytest.mark.dds
@pytest.mark.parametrize("executor", list(ExecutorKind))
def test_a_second_signal_while_closing_is_ignored(executor: ExecutorKind) -> None:
    child = subprocess.Popen([sys.executable, "-c", CHILD, executor.value], cwd=REPO, env=ros_env(next_domain()),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        assert child.stdout.readline() == "up\n", "the node came up"
        child.send_signal(signal.SIGTERM)
        out, err = child.communicate(timeout=TIMEOUT_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0, err
    assert out == "closing\nclosed\n" and "Traceback" not in err, (out, err)


OTHER_THREAD_CHILD = textwrap.dedent(
    """
    import signal
    import sys
    import threading

    from rclpy.node import Node

    from roi_node.live.spin import ExecutorKind, spin_node


    class SignalledOnAnotherThread(Node):
        def __init__(self) -> None:
            super().__init__("signalled_on_another_thread")
            self.create_timer(0.2, self.once)
            self.sent = False

        def once(self) -> None:  # on the executor thread, never the main one
            if not self.sent:
                self.sent = True
                print("signalling", flush=True)
                signal.pthread_kill(threading.get_ident(), signal.SIGINT)

        def close(self) -> None:
            print("closed", flush=True)


    sys.exit(spin_node(SignalledOnAnotherThread, executor=ExecutorKind(sys.argv[1])))
    """
)


@pytest.mark.dds
@pytest.mark.parametrize("executor", list(ExecutorKind))
def test_a_signal_taken_by_another_thread_still_stops_the_node(executor: ExecutorKind) -> None:
    """A process stopped (SIGSTOP, Ctrl-Z) and sent SIGINT has it taken by whichever thread runs first on SIGCONT: here
    the executor's thread takes it. `roi-node record` stopped, interrupted and continued so never exited before."""
    child = subprocess.Popen([sys.executable, "-c", OTHER_THREAD_CHILD, executor.value], cwd=REPO, env=ros_env(next_domain()),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = child.communicate(timeout=TIMEOUT_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0, err
    assert out == "signalling\nclosed\n", (out, err)
