"""RoiLifecycleNode: the live node as a managed (lifecycle) node, for launch systems that sequence their nodes.

The states map onto the stream as follows (StreamNode, live/node.py, does the
per-frame work for both this node and RoiNode):

- configure: read the parameters, load and validate the rig, build the engine
  (URDFs, calibration), create the subscriptions and publishers and start the
  worker. A bad rig or parameter returns FAILURE with one ERROR line naming the
  file and key, and the node stays unconfigured (fix the parameter and
  configure again: every parameter can be set while unconfigured).
- activate: frames are processed and published from the next image on.
- deactivate: images are dropped and counted (`inactive` in the drops of
  /diagnostics and the summary) instead of processed, so nothing is published
  on roi/*; joint states, camera info and URDFs are still taken in, so the
  first frame after activate is synchronised at once. /diagnostics is
  published in both configured states.
- cleanup: the worker stops (its summary line is logged), the engine, the
  subscriptions, publishers and timers and the arms' runtime parameters are
  released.
- shutdown (from any state): the stream stops as in cleanup, and the process
  exits 0 once the transition has been answered.

Every change_state request is answered. One that is no transition of the
current state (activate before configure, configure twice, cleanup while
active, an unknown id or label, anything once finalized) is refused with
success=False and one WARN line naming the request, the state and the
transitions it has; the node stays in its state and, if active, keeps
publishing. (rclpy's own service raises on such a request, which ends the
process unanswered.) A refusal is the client's mistake, not the stream's, so
/diagnostics, which reports the stream, does not count it.
"""

from __future__ import annotations

from lifecycle_msgs.srv import ChangeState
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter

from roi_node.engine.errors import RoiNodeError
from roi_node.engine.short_repr import short_repr
from roi_node.live.node import NODE_NAME, StreamNode
from roi_node.live.params import declare, read
from roi_node.live.runtime_params import undeclare_policy

EXIT_DELAY_S = 0.1  # after the shutdown transition: its ChangeState response goes out first


class RoiLifecycleNode(LifecycleNodeMixin, StreamNode):
    """StreamNode under the lifecycle state machine (see the module docstring)."""

    def __init__(self, *, parameter_overrides: list[Parameter] | None = None, overlap_global_view: bool = False) -> None:
        """`overlap_global_view`: resample the global view on its own thread beside the ROIs (`roi-node run` does)."""
        StreamNode.__init__(self, NODE_NAME, parameter_overrides=parameter_overrides or [])
        self.overlap_global_view = overlap_global_view
        LifecycleNodeMixin.__init__(self, enable_communication_interface=True)
        self._perform_transition = self._service_change_state.callback
        self._service_change_state.callback = self._on_change_state
        self.active = False
        declare(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info("lifecycle node unconfigured: configure loads the rig, activate starts publishing")

    def _on_change_state(self, request: ChangeState.Request, response: ChangeState.Response) -> ChangeState.Response:
        """The change_state service: a transition of the current state is performed (rclpy's callback), any other
        request is refused here, where rclpy would raise."""
        wanted = request.transition
        state_id, state_label = self._state_machine.current_state
        available = self._state_machine.available_transitions  # (id, label, start id, start label, goal id, goal label)
        if any((t[1] == wanted.label) if wanted.label else (t[0] == wanted.id) for t in available):
            return self._perform_transition(request, response)
        labels = {t[0]: t[1] for t in self._state_machine.transition_graph}
        asked = short_repr(wanted.label) if wanted.label else f"{labels.get(wanted.id, 'unknown')} ({wanted.id})"
        offered = ", ".join(f"{t[1]} ({t[0]})" for t in available) or "none (the process is exiting)"
        self.get_logger().warning(
            f"lifecycle: transition {asked} refused: not a transition of state {state_label} ({state_id}); "
            f"its transitions: {offered}"
        )
        response.success = False
        return response

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.params = read(self)
            self._start_stream()
        except RoiNodeError as exc:
            undeclare_policy(self)
            self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        self.get_logger().info("active: processing and publishing")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.get_logger().info("inactive: frames are dropped (counted as inactive) until activated")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_stream()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised (a bug: rclpy logged it): release what exists, back to unconfigured."""
        self.active = False
        if self.policy is not None:
            self._stop_stream()
        undeclare_policy(self)
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        if self.policy is not None:
            self._stop_stream()
        self._exit_timer = self.create_timer(EXIT_DELAY_S, self._exit)
        return TransitionCallbackReturn.SUCCESS

    def _exit(self) -> None:
        """End the process, once the change_state requests already received are answered (refused: finalized);
        any answered here goes out before the next tick ends it."""
        service = self._service_change_state
        answered = False
        while True:
            with service.handle:
                request, header = service.handle.service_take_request(ChangeState.Request)
            if header is None:
                break
            service.send_response(self._on_change_state(request, ChangeState.Response()), header)
            answered = True
        if answered:
            return
        self.destroy_timer(self._exit_timer)
        self.context.try_shutdown()
