"""`--policy grpc://`: what a LeRobot policy server sends back is unpickled only through the allow-list, and the spec is
dispatched and checked before DDS starts. No grpcio or torch here: the pickles are made as LeRobot's server makes them
(a dataclass `lerobot.async_inference.helpers.TimedAction`, NEWOBJ + BUILD), under a stand-in module of that name; the
real server's pickles of torch tensors are read in test/datasets/lerobot/test_policy_grpc.py."""

from __future__ import annotations

import pickle
import sys
import types
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roi_node.cli import main
from roi_node.policy.action_errors import PolicyLoadError
from roi_node.policy.errors import RefusedPickleError
from roi_node.policy.loaders import PolicyKind, policy_kind
from roi_node.policy.remote_grpc import HELPERS, bytes_field, lerobot_pickle, load_grpc, observation_parts, parse_grpc_spec
from roi_node.policy.safe_unpickle import TimedAction, safe_loads
from test.policy.policy_dataset import RIG, export_dataset

SERVER = "grpc://127.0.0.1:8080?policy_type=act&checkpoint=/models/act"


@dataclass
class ServerTimedAction:  # lerobot/async_inference/helpers.py TimedAction, as the server pickles it
    timestamp: float
    timestep: int
    action: Any


ServerTimedAction.__module__, ServerTimedAction.__qualname__ = HELPERS, "TimedAction"  # pickled under lerobot_helpers


class WritesAFile:
    """What a hostile server sends: loading it writes `path` (pathlib.Path.write_text, named as a global)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self) -> tuple[Any, ...]:
        return (Path.write_text, (self.path, "written by a pickle"))


@pytest.fixture
def lerobot_helpers(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """pickle names ServerTimedAction as lerobot.async_inference.helpers.TimedAction while this is on."""
    module = types.ModuleType(HELPERS)
    module.TimedAction = ServerTimedAction  # type: ignore[attr-defined]
    for name in ("lerobot", "lerobot.async_inference"):
        monkeypatch.setitem(sys.modules, name, types.ModuleType(name))
    monkeypatch.setitem(sys.modules, HELPERS, module)
    yield


def chunk_pickle(actions: list[Any]) -> bytes:
    return pickle.dumps([ServerTimedAction(1.0 + i / 30, 7 + i, a) for i, a in enumerate(actions)])


def test_a_chunk_of_timed_actions_loads(lerobot_helpers: None) -> None:
    chunk = np.arange(12, dtype=np.float32).reshape(3, 4)
    payload = chunk_pickle(list(chunk))
    assert b"lerobot.async_inference.helpers" in payload and b"TimedAction" in payload
    loaded = safe_loads(payload, "GetActions from 127.0.0.1:8080")
    assert [type(a) for a in loaded] == [TimedAction] * 3 and [a.timestep for a in loaded] == [7, 8, 9]
    np.testing.assert_array_equal(np.asarray([a.action for a in loaded]), chunk)


def test_a_pickle_that_would_write_a_file_is_refused_naming_it_and_writes_nothing(lerobot_helpers: None, tmp_path: Path) -> None:
    control, target = tmp_path / "control.txt", tmp_path / "target.txt"
    pickle.loads(chunk_pickle([WritesAFile(control)]))  # the payload is real: plain pickle writes the file
    assert control.read_text() == "written by a pickle"
    with pytest.raises(RefusedPickleError) as refused:
        safe_loads(chunk_pickle([WritesAFile(target)]), "GetActions from 127.0.0.1:8080")
    assert not target.exists()
    assert (refused.value.module, refused.value.name) == ("pathlib", "Path.write_text")
    assert str(refused.value) == ("GetActions from 127.0.0.1:8080: refused a pickle naming pathlib.Path.write_text: not one of the "
                                  "classes LeRobot's action messages need, nothing of it was loaded")


@pytest.mark.parametrize(("module", "name"), [("builtins", "eval"), ("os", "system"), ("torch", "load"),
                                              (HELPERS, "TimedObservation"), ("torch.storage", "TypedStorage")])
def test_any_other_global_is_refused(module: str, name: str) -> None:
    payload = b"\x80\x03c" + f"{module}\n{name}\n".encode() + b"X\x01\x00\x00\x001\x85R."  # module.name('1')
    with pytest.raises(RefusedPickleError, match=f"refused a pickle naming {module}.{name}: "):
        safe_loads(payload, "server")


def test_the_messages_sent_name_lerobots_classes_and_frame_as_its_client_does(lerobot_helpers: None) -> None:
    sys.modules[HELPERS].TimedObservation = lambda *args: ("TimedObservation", *args)  # type: ignore[attr-defined]
    image = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    sent = pickle.loads(lerobot_pickle("TimedObservation", (1.5, 4, {"global": image, "state_0": 0.25}, True)))
    assert sent[:3] == ("TimedObservation", 1.5, 4) and sent[4] is True
    np.testing.assert_array_equal(sent[3]["global"], image)
    data = bytes(range(256)) * 20000  # 5 MB: three parts, BEGIN MIDDLE END, as lerobot's send_bytes_in_chunks
    parts = list(observation_parts(data))
    assert [p[:2] for p in parts] == [b"\x08\x01", b"\x08\x02", b"\x08\x03"]
    assert b"".join(bytes_field(p, 2) for p in parts) == data


def test_grpc_specs_are_dispatched_and_checked() -> None:
    assert policy_kind(SERVER) is PolicyKind.GRPC
    target = parse_grpc_spec(SERVER + "&device=cuda&actions_per_chunk=20")
    assert (target.address, target.policy_type, target.checkpoint, target.device, target.actions_per_chunk) == (
        "127.0.0.1:8080", "act", "/models/act", "cuda", 20)
    with pytest.raises(PolicyLoadError, match=r"missing \['checkpoint'\]"):
        parse_grpc_spec("grpc://127.0.0.1:8080?policy_type=act")
    with pytest.raises(PolicyLoadError, match=r"unknown \['chekpoint'\]"):
        parse_grpc_spec("grpc://127.0.0.1:8080?policy_type=act&checkpoint=x&chekpoint=x")
    with pytest.raises(PolicyLoadError, match="expected grpc://HOST:PORT"):
        parse_grpc_spec("grpc://127.0.0.1?policy_type=act&checkpoint=x")


def test_grpc_without_grpcio_is_one_line_before_dds(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "grpc", None)  # import grpc raises ImportError, installed or not
    with pytest.raises(PolicyLoadError, match="needs grpcio and torch"):
        load_grpc(SERVER)
    dataset = export_dataset(tmp_path, fps=30, duration_s=0.5)
    capsys.readouterr()
    assert main(["policy", "run", "--policy", SERVER, "--features", str(dataset), "--config", str(RIG)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"roi-node policy: error: --policy {SERVER}: a grpc:// policy needs grpcio and torch (grpc is not installed "
        "here): pip install 'roi_node[grpc]', or run it with .venv-lerobot's python"]
