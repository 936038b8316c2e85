"""`policy run --policy grpc://`: LeRobot's own PolicyServer serves an ACT policy (random weights, the exported dataset's
features) and its action chunks drive the simulated bimanual rig for 10 s.

The server is lerobot's `python -m lerobot.async_inference.policy_server`,
unchanged, in a process of its own; `roi-node policy run` is its robot client
(Ready, SendPolicyInstructions with the checkpoint, then SendObservations and
GetActions per chunk), reading each answer through the allow-list. As real
processes on one DDS domain: the sim follows the commands, the node crops,
the recorder records the commands and joint states. Afterwards: the server
says it answered observations with chunks, the run refused nothing, and the
recorded joint states end closer to the last command than they started.
Against a scripted AsyncInference service: a chunk of real torch tensors
pickled as LeRobot's server pickles it loads, what the client sent unpickles
as lerobot's own RemotePolicyConfig and TimedObservation, and a pickle naming
a global outside the allow-list is refused with nothing written.
"""

from __future__ import annotations

import pickle
import signal
import socket
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import pytest

from roi_node.policy.errors import RefusedPickleError, RemotePolicyError
from roi_node.policy.features import FeatureSource, ImageFeature, PolicyFeatures
from roi_node.policy.remote_grpc import bytes_field, encode_bytes_field, load_grpc
from roi_node.wire import topics
from test.dds.harness import LOSSLESS_TRANSPORT, next_domain, node_args, process, ros_env, wait_until
from test.policy.policy_dataset import RIG, export_dataset

pytest.importorskip("lerobot.async_inference.helpers")  # not policy_server: importing it writes logs/ here
from lerobot.datasets.utils import build_dataset_frame

from test.datasets.lerobot.act_policy import save_random_act
from test.datasets.lerobot.test_act_closed_loop import DiagnosticsListener, joint_series

FPS = 30
ROLLOUT_COMMANDS = 10 * FPS  # 10 s of commands at 30 Hz
COMMAND_TOPIC = "joint_commands"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    except OSError:
        return False
    return True


@pytest.mark.dds
def test_lerobots_policy_server_drives_the_sim_through_grpc(tmp_path: Path) -> None:
    dataset = export_dataset(tmp_path / "data", fps=FPS, duration_s=2.0)
    act = tmp_path / "act"
    save_random_act(dataset, act, chunk_size=FPS)
    port = free_port()
    domain = next_domain()
    env = ros_env(domain)
    rollout = tmp_path / "rollout"
    server_dir = tmp_path / "server"  # lerobot's server writes its logs/ under its working directory
    server_dir.mkdir()
    server = ["-m", "lerobot.async_inference.policy_server", "--host=127.0.0.1", f"--port={port}", f"--fps={FPS}",
              "--inference_latency=0", "--obs_queue_timeout=5"]
    sim = ["-m", "roi_node.cli", "sim", "--config", str(RIG), "--follow-commands", COMMAND_TOPIC, "--duration", "600",
           "--rate-hz", str(FPS), "--min-subscribers", "1", "--late-frames", "send"]
    spec = f"grpc://127.0.0.1:{port}?policy_type=act&checkpoint={quote(str(act), safe='/')}"
    policy = ["-m", "roi_node.cli", "policy", "run", "--policy", spec, "--features", str(act), "--dataset", str(dataset),
              "--config", str(RIG), "--command-topic", COMMAND_TOPIC, "--timeout-s", "120"]
    record_topics = [topics.JOINT_STATES, COMMAND_TOPIC]
    listener = DiagnosticsListener(domain)
    try:
        with process(server, env, tmp_path / "server.log", cwd=server_dir) as policy_server:
            assert wait_until(lambda: listening(port) or policy_server.poll() is not None, 120.0)
            assert policy_server.poll() is None, (tmp_path / "server.log").read_text()
            with process(node_args(RIG, *LOSSLESS_TRANSPORT), env, tmp_path / "node.log"), \
                    process(["-m", "roi_node.cli", "record", "-o", str(rollout), "--topics", *record_topics], env,
                            tmp_path / "record.log") as recorder, \
                    process(sim, env, tmp_path / "sim.log") as simulator, process(policy, env, tmp_path / "policy.log") as runner:
                published = lambda: int(listener.policy_status().get("actions_published", 0) or 0)  # noqa: E731
                ended = lambda: runner.poll() is not None or simulator.poll() is not None  # noqa: E731
                # the policy publishes from its start (the measured start until the first chunk), the recorder's reader
                # matches its writer a moment later: a second of commands more than the recorder is asked to hold
                assert wait_until(lambda: published() >= ROLLOUT_COMMANDS + FPS or ended(), 600.0), (tmp_path / "policy.log").read_text()
                assert not ended(), (tmp_path / "policy.log").read_text() + (tmp_path / "sim.log").read_text()
                runner.send_signal(signal.SIGINT)
                assert runner.wait(timeout=60) == 0, (tmp_path / "policy.log").read_text()
                recorder.send_signal(signal.SIGINT)
                assert recorder.wait(timeout=60) == 0
            status = listener.policy_status()
    finally:
        listener.close()
    log = (tmp_path / "policy.log").read_text()
    assert f"grpc://127.0.0.1:{port}" in log and "(grpc)" in log
    assert status["refused_by_kind"] == {} and status["chunks"] >= 2, status
    server_log = (tmp_path / "server.log").read_text()
    assert "Action chunk #0 generated" in server_log and "Action chunk #1 generated" in server_log, server_log[-3000:]

    commands = joint_series(rollout, "/" + COMMAND_TOPIC)
    states = joint_series(rollout, topics.absolute(topics.JOINT_STATES))
    assert len(commands) >= ROLLOUT_COMMANDS and len({tuple(c.values()) for _, c in commands}) > 1  # the chunks moved it
    last_command = commands[-1][1]
    first_state = next(s for t, s in states if t >= commands[0][0])
    final_state = states[-1][1]
    names = sorted(last_command)
    start_gap = np.array([abs(first_state[n] - last_command[n]) for n in names])
    end_gap = np.array([abs(final_state[n] - last_command[n]) for n in names])
    assert end_gap.sum() < start_gap.sum(), f"the sim did not follow: start gap {start_gap}, end gap {end_gap}"


class ScriptedServer:
    """An AsyncInference service answering GetActions with `answer` (a pickle), keeping what it was sent."""

    def __init__(self, answer: bytes) -> None:
        import grpc

        self.received: dict[str, list[bytes]] = {"Ready": [], "SendPolicyInstructions": [], "SendObservations": [], "GetActions": []}

        def unary(method: str, reply: bytes) -> Any:
            return grpc.unary_unary_rpc_method_handler(lambda request, _: (self.received[method].append(request), reply)[1])

        def observations(requests: Iterator[bytes], _: Any) -> bytes:
            self.received["SendObservations"].append(b"".join(bytes_field(r, 2) for r in requests))
            return b""

        handlers = {"Ready": unary("Ready", b""), "SendPolicyInstructions": unary("SendPolicyInstructions", b""),
                    "GetActions": unary("GetActions", encode_bytes_field(1, answer)),
                    "SendObservations": grpc.stream_unary_rpc_method_handler(observations)}
        self.server = grpc.server(ThreadPoolExecutor(max_workers=2))
        self.server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler("transport.AsyncInference", handlers),))
        self.port = self.server.add_insecure_port("127.0.0.1:0")
        self.server.start()

    def __enter__(self) -> ScriptedServer:
        return self

    def __exit__(self, *_: object) -> None:
        self.server.stop(None)


class WritesAFile:
    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self) -> tuple[Any, ...]:
        return (Path.write_text, (self.path, "written by a pickle"))


BATCH = {"observation.images.global": np.full((3, 4, 6), 128 / 255, dtype=np.float32),
         "observation.state": np.array([0.5, -1.0], dtype=np.float32), "task": "hold"}


def test_a_real_chunk_of_torch_tensors_loads_and_the_messages_sent_are_lerobots() -> None:
    import torch
    from lerobot.async_inference.helpers import RemotePolicyConfig, TimedAction, TimedObservation

    chunk = torch.arange(12, dtype=torch.float32).reshape(3, 4)
    answer = pickle.dumps([TimedAction(1.0 + i / FPS, i, action) for i, action in enumerate(list(chunk))])
    with ScriptedServer(answer) as server:
        policy = load_grpc(f"grpc://127.0.0.1:{server.port}?policy_type=act&checkpoint=user/act&device=cuda")
        np.testing.assert_array_equal(policy.act(BATCH), chunk.numpy())
    config = pickle.loads(bytes_field(server.received["SendPolicyInstructions"][0], 1))
    assert isinstance(config, RemotePolicyConfig)
    assert (config.policy_type, config.pretrained_name_or_path, config.device) == ("act", "user/act", "cuda")
    observation = pickle.loads(server.received["SendObservations"][0])
    assert isinstance(observation, TimedObservation) and observation.must_go and observation.get_timestep() == 0
    frame = build_dataset_frame(config.lerobot_features, observation.get_observation(), prefix="observation")
    np.testing.assert_array_equal(frame["observation.state"], BATCH["observation.state"])
    assert frame["observation.images.global"].dtype == np.uint8 and (frame["observation.images.global"] == 128).all()
    assert frame["observation.images.global"].shape == (4, 6, 3) and observation.get_observation()["task"] == "hold"


def test_a_pickle_outside_the_allow_list_is_refused_and_writes_nothing(tmp_path: Path) -> None:
    from lerobot.async_inference.helpers import TimedAction

    target = tmp_path / "written.txt"
    with ScriptedServer(pickle.dumps([TimedAction(1.0, 0, WritesAFile(target))])) as server:
        policy = load_grpc(f"grpc://127.0.0.1:{server.port}?policy_type=act&checkpoint=user/act")
        with pytest.raises(RefusedPickleError) as refused:
            policy.act(BATCH)
    assert not target.exists() and (refused.value.module, refused.value.name) == ("pathlib", "Path.write_text")
    assert str(refused.value).startswith(f"GetActions from 127.0.0.1:{server.port}: refused a pickle naming pathlib.Path.write_text")


def test_a_server_that_is_not_there_or_answers_no_actions_is_one_line_naming_the_call() -> None:
    port = free_port()  # nothing listens on it
    with pytest.raises(RemotePolicyError, match=rf"^policy server 127.0.0.1:{port}: Ready: UNAVAILABLE: "):
        load_grpc(f"grpc://127.0.0.1:{port}?policy_type=act&checkpoint=user/act").act(BATCH)
    with ScriptedServer(b"") as server, pytest.raises(RemotePolicyError, match="GetActions answered no actions"):
        load_grpc(f"grpc://127.0.0.1:{server.port}?policy_type=act&checkpoint=user/act").act(BATCH)


def test_connect_sets_the_server_up_before_any_observation_declaring_what_the_first_act_would() -> None:
    """The run connects after the preflight (LoadedPolicy.connect): the server loads the checkpoint before the first
    observation, with the features a client connecting at its first act declares for observations of those features."""
    features = PolicyFeatures(Path("features"), FeatureSource.DATASET, (ImageFeature("observation.images.global", 3, 4, 6),),
                              ("a", "b"), ("a", "b"), (), FPS, None)
    with ScriptedServer(b"") as early, ScriptedServer(pickle.dumps([])) as late:
        connected = load_grpc(f"grpc://127.0.0.1:{early.port}?policy_type=act&checkpoint=user/act", features)
        assert connected.connect is not None
        connected.connect()
        assert len(early.received["SendPolicyInstructions"]) == 1 and not early.received["SendObservations"]
        with pytest.raises(RemotePolicyError):  # an empty list of actions: only the setup it sent is looked at
            load_grpc(f"grpc://127.0.0.1:{late.port}?policy_type=act&checkpoint=user/act").act(BATCH)
    declared = [pickle.loads(bytes_field(server.received["SendPolicyInstructions"][0], 1)).lerobot_features
                for server in (early, late)]
    assert declared[0] == declared[1]
