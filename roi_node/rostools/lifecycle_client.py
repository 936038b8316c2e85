"""`roi-node lifecycle get|set|list`: drive a managed (lifecycle) node by transition label, as `ros2 lifecycle`.

Through the node's lifecycle_msgs services `~/get_state`, `~/get_available_transitions` and `~/change_state`.
`set` first asks which transitions the current state has and sends the one with the label asked for (its id and
label: the three shutdown transitions share the label `shutdown`), so a label the state does not have is
answered here, naming the state and its transitions, without a request the node would refuse.

Printed as `ros2 lifecycle` prints: `get` says `inactive [2]`; `set` says `Transitioning successful`, or on
stderr why not; `list` gives each transition as `- configure [1]` with its start and goal states.

Exit codes: 0 done; 1 the node is reachable but the transition was not made (the state has no such transition,
or the node's transition callback failed: its log says why, e.g. a rig that does not load at configure); 2 the
command could not be carried out (bad input, the node or its services not reached).
"""

from __future__ import annotations

from dataclasses import dataclass

from lifecycle_msgs.msg import TransitionDescription
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState

from roi_node.rostools.lifecycle_labels import TransitionLabel
from roi_node.rostools.remote_node import RemoteNode

NOT_LIFECYCLE_HINT = "is it a lifecycle node? `roi-node run --lifecycle` starts one"


@dataclass(frozen=True)
class LifecycleState:
    """A primary or transition state as the node names it."""

    id: int
    label: str

    def __str__(self) -> str:
        return f"{self.label} [{self.id}]"


@dataclass(frozen=True)
class AvailableTransition:
    """A transition the current state has: its id and label and the states it leads from and to."""

    id: int
    label: str
    start: LifecycleState
    goal: LifecycleState

    @classmethod
    def from_msg(cls, msg: TransitionDescription) -> AvailableTransition:
        return cls(msg.transition.id, msg.transition.label, LifecycleState(msg.start_state.id, msg.start_state.label),
                   LifecycleState(msg.goal_state.id, msg.goal_state.label))

    def listing(self) -> str:
        """`ros2 lifecycle list`'s lines for this transition."""
        return f"- {self.label} [{self.id}]\n\tStart: {self.start.label}\n\tGoal: {self.goal.label}"


@dataclass(frozen=True)
class TransitionOutcome:
    """What `set` did: whether the node made the transition; when it did not, the state the node is in."""

    done: bool
    state: LifecycleState | None  # None when done: the node may have moved on (or exited, after shutdown)
    available: tuple[AvailableTransition, ...]
    requested_available: bool  # False: the state has no transition of that label, nothing was sent

    def line(self, label: TransitionLabel) -> str:
        if self.done:
            return "Transitioning successful"
        if not self.requested_available:
            offered = ", ".join(f"{t.label} [{t.id}]" for t in self.available) or "none"
            return f"Transition {label} not available in state {self.state}; its transitions: {offered}"
        return (f"Transitioning failed: {label} was refused and the node is in state {self.state} "
                "(the node's log says why)")


def get_state(remote: RemoteNode) -> LifecycleState:
    client = remote.client(GetState, "get_state", hint=NOT_LIFECYCLE_HINT)
    state = remote.call(client, GetState.Request()).current_state
    return LifecycleState(state.id, state.label)


def available_transitions(remote: RemoteNode) -> tuple[AvailableTransition, ...]:
    client = remote.client(GetAvailableTransitions, "get_available_transitions", hint=NOT_LIFECYCLE_HINT)
    response = remote.call(client, GetAvailableTransitions.Request())
    return tuple(AvailableTransition.from_msg(t) for t in response.available_transitions)


def change_state(remote: RemoteNode, label: TransitionLabel) -> TransitionOutcome:
    """Make the transition labelled `label` if the current state has it; the state afterwards either way."""
    available = available_transitions(remote)
    chosen = next((t for t in available if t.label == label), None)
    if chosen is None:
        return TransitionOutcome(False, get_state(remote), available, requested_available=False)
    client = remote.client(ChangeState, "change_state", hint=NOT_LIFECYCLE_HINT)
    request = ChangeState.Request()
    request.transition.id = chosen.id
    request.transition.label = chosen.label
    if remote.call(client, request).success:
        return TransitionOutcome(True, None, available, requested_available=True)
    return TransitionOutcome(False, get_state(remote), available, requested_available=True)
