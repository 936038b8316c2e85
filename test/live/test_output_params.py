"""The node's output parameters (output_transport, jpeg_quality, overlay), read as the node reads them."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

from roi_node.engine.errors import ParameterError
from roi_node.live.params import NodeParams, declare_and_read
from roi_node.wire.compressed_outputs import OutputTransport
from test.dds.harness import next_domain
from test.support.paths import CONFIG

pytestmark = pytest.mark.dds  # a DDS participant, on a domain of its own (live/harness.py next_domain)

@pytest.fixture(scope="module")
def context() -> Iterator[Context]:
    context = Context()
    rclpy.init(context=context, domain_id=next_domain())  # the run's own domains, like the live tests
    yield context
    context.try_shutdown()


def read(context: Context, **overrides: object) -> NodeParams:
    parameters = [Parameter("config", value=str(CONFIG / "rig_demo_bimanual.yaml"))]
    parameters += [Parameter(name, value=value) for name, value in overrides.items()]
    node = Node("roi_node", context=context, parameter_overrides=parameters, start_parameter_services=False)
    try:
        return declare_and_read(node)
    finally:
        node.destroy_node()


def test_defaults_are_raw_outputs_at_quality_90_with_the_overlay(context: Context) -> None:
    params = read(context)
    assert params.output_transport is OutputTransport.RAW and params.jpeg_quality == 90 and params.overlay is True
    both = read(context, output_transport="both", jpeg_quality=1, overlay=False)
    assert both.output_transport.raw and both.output_transport.compressed and both.jpeg_quality == 1 and not both.overlay


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"output_transport": "jpeg"}, "parameter output_transport: 'jpeg' is not one of raw, compressed, both"),
        ({"jpeg_quality": 101}, "parameter jpeg_quality: expected an integer in 1..100, got 101"),
        ({"jpeg_quality": 0}, "parameter jpeg_quality: expected an integer in 1..100, got 0"),
        ({"jpeg_quality": 90.0}, "parameter jpeg_quality: expected an integer, got 90.0 (double)"),
        ({"overlay": "yes"}, "parameter overlay: expected a bool, got 'yes' (string)"),
        # rclpy's QoS binding takes a depth below 2**31 only: beyond, the node ended in a TypeError from its constructor
        ({"qos.subscription_depth": 2**63 - 1}, "parameter qos.subscription_depth: expected an integer in 1..100000, "
         "got 9223372036854775807"),
        ({"qos.publisher_depth": 0}, "parameter qos.publisher_depth: expected an integer in 1..100000, got 0"),
        ({"qos.joint_state_depth": 2**31}, "parameter qos.joint_state_depth: expected an integer in 1..100000, got 2147483648"),
        # the node pre-faulted memory for every pending frame (an out-of-memory kill) and gave cv2 a C int
        ({"sync.max_pending_frames": 2**63 - 1}, "parameter sync.max_pending_frames: expected an integer in 1..1000, got "
         "9223372036854775807"),
        ({"opencv_threads": 2**40}, "parameter opencv_threads: expected an integer in 1..1024, got 1099511627776"),
        # rclpy's InvalidTopicNameException named no parameter and ended the node as an internal error
        ({"image_topic": ""}, "parameter image_topic: '' is not a topic name: topic name must not be empty string"),
        ({"camera_info_topic": "bad topic"}, "parameter camera_info_topic: 'bad topic' is not a topic name: topic name must "
         "not contain characters other than alphanumerics, '_', '~', '{', or '}'"),
        ({"joint_state_topics": ["joint_states", "joint states"]}, "parameter joint_state_topics: 'joint states' is not a topic name: "),
        ({"command_topic": "1cmd"}, "parameter command_topic: '1cmd' is not a topic name: "),
    ],
)
def test_bad_output_parameters_are_refused_naming_the_parameter(context: Context, overrides: dict[str, object],
                                                                 message: str) -> None:
    with pytest.raises(ParameterError) as refused:
        read(context, **overrides)
    assert (str(refused.value).startswith(message) and message.endswith(": ")) or str(refused.value) == message, str(refused.value)
