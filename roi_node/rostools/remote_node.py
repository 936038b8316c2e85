"""A command-line client's side of another node: its name, its presence on the graph, one service call with a deadline.

What `ros2 param` and `ros2 lifecycle` do through ros2cli, on public rclpy API only: a pip-installed ROS 2 has
rclpy but no `ros2` command. The client is a hidden node (its name starts with an underscore, as ros2cli's do) in
a context of its own, started without rclpy's signal handlers, so Ctrl-C is Python's KeyboardInterrupt, which the
CLI reports as `interrupted`.

Every way of not reaching the node is one RemoteNodeError naming the node or service and how long it waited
(the CLI prints it as one line, exit 2): the node is not on the graph, it does not offer the service, or it did
not answer. Node and service are waited for under one deadline, `timeout_s` from the start, as `ros2 param
--timeout` waits for the node; an answer has a deadline of its own, since a lifecycle configure may take as long
as loading the rig does.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import rclpy
from rclpy.client import Client
from rclpy.context import Context
from rclpy.exceptions import InvalidNamespaceException, InvalidNodeNameException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.validate_namespace import validate_namespace
from rclpy.validate_node_name import validate_node_name

from roi_node.engine.errors import RoiNodeError, UsageError

GRAPH_POLL_S = 0.05  # how often the graph is looked at while waiting for the node to appear
NODES_NAMED_AT_MOST = 8  # a "not found" line names at most this many of the nodes it saw


class RemoteNodeError(RoiNodeError):
    """The node, its service or its answer could not be reached; `node` is the node's full name."""

    def __init__(self, node: str, message: str) -> None:
        super().__init__(message)
        self.node = node


class NodeNotFoundError(RemoteNodeError):
    """No node of that name appeared on the graph within the timeout."""

    def __init__(self, node: str, timeout_s: float, domain_id: int, nodes_seen: Sequence[str]) -> None:
        shown = ", ".join(nodes_seen[:NODES_NAMED_AT_MOST]) + (", ..." if len(nodes_seen) > NODES_NAMED_AT_MOST else "")
        super().__init__(node, f"node {node} not found within {timeout_s:g} s on ROS domain {domain_id} "
                               f"(nodes seen: {shown or 'none'})")
        self.timeout_s = timeout_s
        self.domain_id = domain_id
        self.nodes_seen = tuple(nodes_seen)


class ServiceUnavailableError(RemoteNodeError):
    """The node is on the graph but did not offer the service within the timeout; `hint` says what that may mean."""

    def __init__(self, node: str, service: str, timeout_s: float, hint: str) -> None:
        super().__init__(node, f"service {service} not available within {timeout_s:g} s{f' ({hint})' if hint else ''}")
        self.service = service
        self.timeout_s = timeout_s


class NoAnswerError(RemoteNodeError):
    """A request was sent but not answered within the answer timeout."""

    def __init__(self, node: str, service: str, timeout_s: float) -> None:
        super().__init__(node, f"service {service} did not answer within {timeout_s:g} s")
        self.service = service
        self.timeout_s = timeout_s


@dataclass(frozen=True)
class NodeName:
    """A node's namespace ("/" or "/a/b") and base name, as the graph lists them."""

    namespace: str
    name: str

    @property
    def full_name(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.name}"

    def service(self, suffix: str) -> str:
        """The node's private service `~/<suffix>`, e.g. /roi_node/get_parameters."""
        return f"{self.full_name}/{suffix}"


def parse_node_name(text: str) -> NodeName:
    """`roi_node`, `/roi_node` or `/rig1/roi_node`; a relative name is in the root namespace, as ros2cli takes it."""
    full = text if text.startswith("/") else f"/{text}"
    namespace, _, name = full.rpartition("/")
    try:
        validate_node_name(name)
        validate_namespace(namespace or "/")
    except (InvalidNodeNameException, InvalidNamespaceException) as exc:
        reason = str(exc).splitlines()[0].rstrip(":")  # rclpy's first line; the next ones point at the character
        raise UsageError(f"node name {text!r}: {reason}") from None
    return NodeName(namespace or "/", name)


@dataclass(frozen=True)
class Deadlines:
    """How long to wait for the node and its services together (`reach_s`), and for each answer (`answer_s`)."""

    reach_s: float
    answer_s: float


@contextlib.contextmanager
def client_node(ros_args: Sequence[str] = ()) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """A hidden node of this process (`_roi_node_cli_<pid>`) in a context of its own, with an executor to spin it."""
    context = Context()
    rclpy.init(args=["roi_node", *ros_args], context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = Node(f"_roi_node_cli_{os.getpid()}", context=context, start_parameter_services=False)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        try:
            yield node, executor
        finally:
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
    finally:
        context.try_shutdown()


class RemoteNode:
    """A hidden client node in its own rclpy context, on the graph of one target node; use it in a `with` block.

    Entering waits for the target to appear on the graph (NodeNotFoundError otherwise); `call` waits for the
    service within what is left of the same deadline, then for the answer.
    """

    def __init__(self, target: NodeName, deadlines: Deadlines, ros_args: Sequence[str] = ()) -> None:
        self.target = target
        self.deadlines = deadlines
        self._ros_args = list(ros_args)
        self._stack = contextlib.ExitStack()
        self._node: Node | None = None
        self._executor: SingleThreadedExecutor | None = None
        self._reach_deadline = 0.0

    def __enter__(self) -> RemoteNode:
        self._reach_deadline = time.monotonic() + self.deadlines.reach_s
        with contextlib.ExitStack() as stack:
            self._node, self._executor = stack.enter_context(client_node(self._ros_args))
            self._wait_for_target()
            self._stack = stack.pop_all()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._stack.close()

    @property
    def node(self) -> Node:
        assert self._node is not None, "RemoteNode used outside its with block"
        return self._node

    @property
    def domain_id(self) -> int:
        return int(self.node.context.get_domain_id())

    def _graph_nodes(self) -> list[str]:
        return sorted(NodeName(ns or "/", name).full_name for name, ns in self.node.get_node_names_and_namespaces())

    def _wait_for_target(self) -> None:
        """Until the target is on the graph (discovery takes a moment after the client node starts)."""
        while self.target.full_name not in (seen := self._graph_nodes()):
            if time.monotonic() > self._reach_deadline:
                others = [n for n in seen if not n.split("/")[-1].startswith("_")]  # hidden nodes (CLI clients) left out
                raise NodeNotFoundError(self.target.full_name, self.deadlines.reach_s, self.domain_id, others)
            time.sleep(GRAPH_POLL_S)

    def client(self, service_type: Any, suffix: str, *, hint: str = "") -> Client:
        """A client of the target's `~/<suffix>` service once the service is offered, within the reach deadline."""
        name = self.target.service(suffix)
        client = self.node.create_client(service_type, name)
        remaining_s = max(0.0, self._reach_deadline - time.monotonic())
        if not client.wait_for_service(timeout_sec=remaining_s):
            self.node.destroy_client(client)
            raise ServiceUnavailableError(self.target.full_name, name, self.deadlines.reach_s, hint)
        return client

    def call(self, client: Client, request: Any) -> Any:
        """Send `request` and spin until it is answered, within the answer deadline."""
        assert self._executor is not None
        future = client.call_async(request)
        self._executor.spin_until_future_complete(future, timeout_sec=self.deadlines.answer_s)
        if not future.done():
            client.remove_pending_request(future)
            raise NoAnswerError(self.target.full_name, client.srv_name, self.deadlines.answer_s)
        return future.result()
