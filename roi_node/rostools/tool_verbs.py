"""`roi-node param`, `lifecycle` and `diagnostics`: stand-ins for the `ros2` commands a pip-installed ROS 2 lacks.

Each works on any node, not only roi_node, through the standard services and topics (rostools/param_client.py,
rostools/lifecycle_client.py, rostools/diagnostics_view.py); rclpy is imported only when one of them runs. A node or
service not reached within --timeout-s, or no /diagnostics message within it, is one line and exit 2; a set or
transition the node refuses is its reason and exit 1.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from roi_node.rostools.lifecycle_labels import TransitionLabel
from roi_node.util.arg_types import float_at_least

if TYPE_CHECKING:
    from roi_node.rostools.remote_node import RemoteNode

# a new process finds a running node in 1-3 s on an idle machine, and took more than 5 s beside a busy one; the wait
# ends as soon as the node (service, message) is there, so only a command that fails waits this long
DEFAULT_TIMEOUT_S = 15.0
DEFAULT_ANSWER_TIMEOUT_S = 30.0  # a lifecycle configure loads the rig (URDFs, calibration) before it answers
REFUSED = 1  # the node answered no (a set it refused, a transition it did not make)


def _remote(args: argparse.Namespace) -> RemoteNode:
    """The client of the node the verb names (rclpy is imported here, when a verb runs, not when the CLI parses)."""
    from roi_node.rostools.remote_node import Deadlines, RemoteNode, parse_node_name

    return RemoteNode(parse_node_name(args.node), Deadlines(args.timeout_s, args.answer_timeout_s), args.ros_args)


def _cmd_param_list(args: argparse.Namespace) -> int:
    from roi_node.rostools.param_client import list_names, type_words

    with _remote(args) as remote:
        names = list_names(remote, args.param_prefixes)
        types = type_words(remote, names) if args.param_type and names else {}
    for name in names:
        print(f"  {name} (type: {types[name]})" if args.param_type else f"  {name}")
    return 0


def _cmd_param_get(args: argparse.Namespace) -> int:
    from roi_node.rostools.param_client import get_entries, get_line

    with _remote(args) as remote:
        (entry,) = get_entries(remote, [args.name])
    print(get_line(entry, hide_type=args.hide_type))
    return 0


def _cmd_param_set(args: argparse.Namespace) -> int:
    from roi_node.rostools.param_client import parse_value, set_line, set_value

    value = parse_value(args.value)
    with _remote(args) as remote:
        result = set_value(remote, args.name, value)
    print(set_line(result), file=sys.stdout if result.successful else sys.stderr)
    return 0 if result.successful else REFUSED


def _cmd_param_dump(args: argparse.Namespace) -> int:
    from roi_node.rostools.param_client import dump_yaml, get_entries, list_names

    with _remote(args) as remote:
        names = list_names(remote)
        entries = get_entries(remote, names) if names else []
    sys.stdout.write(dump_yaml(remote.target.full_name, entries))
    return 0


def _cmd_lifecycle_get(args: argparse.Namespace) -> int:
    from roi_node.rostools.lifecycle_client import get_state

    with _remote(args) as remote:
        state = get_state(remote)
    print(state)
    return 0


def _cmd_lifecycle_list(args: argparse.Namespace) -> int:
    from roi_node.rostools.lifecycle_client import available_transitions

    with _remote(args) as remote:
        transitions = available_transitions(remote)
    for transition in transitions:
        print(transition.listing())
    return 0


def _cmd_lifecycle_set(args: argparse.Namespace) -> int:
    from roi_node.rostools.lifecycle_client import change_state

    label = TransitionLabel(args.label)
    with _remote(args) as remote:
        outcome = change_state(remote, label)
    print(outcome.line(label), file=sys.stdout if outcome.done else sys.stderr)
    return 0 if outcome.done else REFUSED


def _cmd_diagnostics(args: argparse.Namespace) -> int:
    from roi_node.rostools.diagnostics_view import watch

    return watch(args.ros_args, once=args.once, timeout_s=args.timeout_s)


def _remote_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("node", help="the node's name: roi_node, /roi_node or /namespace/roi_node")
    parser.add_argument("--timeout-s", type=float_at_least(0.0), default=DEFAULT_TIMEOUT_S, metavar="S",
                        help=f"wait this long for the node and its service to appear (default: {DEFAULT_TIMEOUT_S:g})")
    parser.add_argument("--answer-timeout-s", type=float_at_least(0.0), default=DEFAULT_ANSWER_TIMEOUT_S, metavar="S",
                        help=f"wait this long for each answer (default: {DEFAULT_ANSWER_TIMEOUT_S:g})")


def _action(actions: argparse._SubParsersAction[argparse.ArgumentParser], name: str, summary: str,
            description: str) -> argparse.ArgumentParser:
    """A verb's action (`param get`) with the node argument and the timeouts every one of them takes."""
    parser = actions.add_parser(name, help=summary, description=description)
    _remote_arguments(parser)
    return parser


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    param = verbs.add_parser(
        "param",
        help="list, get, set or dump a running node's parameters (`ros2 param`)",
        description="A node's parameters through its parameter services, printed as `ros2 param` prints them. "
        "`set` reads the value as YAML (1.5 a double, 40 an integer, true a bool, [1.0, 2.0] a double array, else "
        "a string); a set the node refuses prints its reason and exits 1. `dump` prints the YAML --params-file "
        "reads back. ROS arguments for this client follow --ros-args.",
    )
    actions = param.add_subparsers(dest="action", required=True, metavar="<action>")
    listing = _action(actions, "list", "the node's parameter names",
                      "The node's parameter names, sorted and indented as `ros2 param list` prints them.")
    listing.add_argument("--param-type", action="store_true", help="each name's type too")
    listing.add_argument("--param-prefixes", nargs="+", default=[], metavar="PREFIX", help="only names under these prefixes")
    listing.set_defaults(func=_cmd_param_list)
    get = _action(actions, "get", "one parameter's value",
                  "One parameter's value with its type, as `ros2 param get` prints it (`Double value is: 1.5`).")
    get.add_argument("name", help="the parameter, e.g. arms.left.offset_px")
    get.add_argument("--hide-type", action="store_true", help="the value only")
    get.set_defaults(func=_cmd_param_get)
    put = _action(actions, "set", "set one parameter",
                  "Set one parameter through the node's set_parameters service; the value is read as YAML. A value "
                  "the node refuses prints its reason on stderr and exits 1.")
    put.add_argument("name", help="the parameter, e.g. arms.left.offset_px")
    put.add_argument("value", help="the value as YAML, e.g. 40.0, true, '[1.0, 1.0]'")
    put.set_defaults(func=_cmd_param_set)
    dump = _action(actions, "dump", "every parameter as a --params-file YAML",
                   "Every parameter of the node as the YAML that --params-file reads back (`/node: ros__parameters:` "
                   "with dotted names nested), as `ros2 param dump` writes it.")
    dump.set_defaults(func=_cmd_param_dump)

    lifecycle = verbs.add_parser(
        "lifecycle",
        help="get or change a lifecycle node's state (`ros2 lifecycle`)",
        description="A managed node's state through its lifecycle services: `get` its state, `list` the transitions "
        "it has, `set` one by label. A transition the state does not have, or one the node fails, is one line on "
        "stderr and exit 1.",
    )
    steps = lifecycle.add_subparsers(dest="action", required=True, metavar="<action>")
    _action(steps, "get", "the node's current state",
            "The lifecycle node's current state with its id, e.g. `inactive [2]`.").set_defaults(func=_cmd_lifecycle_get)
    _action(steps, "list", "the transitions of the current state",
            "The transitions the lifecycle node's current state has, each with its start and goal states."
            ).set_defaults(func=_cmd_lifecycle_list)
    change = _action(steps, "set", "make a transition by label",
                     "Make a transition by its label; one the state does not have, or one the node fails, is one "
                     "line on stderr and exit 1.")
    change.add_argument("label", choices=[label.value for label in TransitionLabel])
    change.set_defaults(func=_cmd_lifecycle_set)

    diagnostics = verbs.add_parser(
        "diagnostics",
        help="watch /diagnostics as one table (rates, drops, latency, per-arm validity)",
        description="The newest /diagnostics statuses as one table, redrawn as they arrive until Ctrl-C; with --once "
        "or when the output is not a terminal, one table after the first message. roi_node's rates, drops by "
        "reason, latency p50/p99 and per-arm validity are picked out. ROS arguments follow --ros-args.",
    )
    diagnostics.add_argument("--once", action="store_true", help="print one table after the first message and exit")
    diagnostics.add_argument("--timeout-s", type=float_at_least(0.0), default=DEFAULT_TIMEOUT_S, metavar="S",
                             help=f"give up when no message arrives this long (default: {DEFAULT_TIMEOUT_S:g})")
    diagnostics.set_defaults(func=_cmd_diagnostics)
