"""RoiLifecycleNode: the live node as a managed (lifecycle) node, for launch systems that sequence their nodes.

The states map onto the stream as follows (StreamNode, ros/node.py, does the
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
"""

from __future__ import annotations

from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter

from ..core.errors import RoiNodeError
from .node import NODE_NAME, StreamNode
from .params import declare, read
from .runtime_params import undeclare_policy

EXIT_DELAY_S = 0.1  # after the shutdown transition: its ChangeState response goes out first


class RoiLifecycleNode(LifecycleNodeMixin, StreamNode):
    """StreamNode under the lifecycle state machine (see the module docstring)."""

    def __init__(self, *, parameter_overrides: list[Parameter] | None = None) -> None:
        StreamNode.__init__(self, NODE_NAME, parameter_overrides=parameter_overrides or [])
        LifecycleNodeMixin.__init__(self, enable_communication_interface=True)
        self.active = False
        declare(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info("lifecycle node unconfigured: configure loads the rig, activate starts publishing")

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
        self.destroy_timer(self._exit_timer)
        self.context.try_shutdown()
