"""A Node.js reader built like Foxglove's (npm @mcap/core + @foxglove/rosmsg2-serialization) decodes an ROI bag.

The bag is written by `replay_bag` (BagWriter, McapFileWriter) with raw and
compressed image outputs and the overlay; test/js/read_bag.mjs decodes every
message with the schemas the file carries and prints JSON, compared here
with what rosbags reads from the same bag. The npm packages are installed
(`npm ci`, pinned by test/js/package-lock.json) into a cache folder outside
the repository, once. Skipped only when `node` is not installed.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import typestore
from roi_node.offline.replay import replay_bag
from test.support.paths import REPO
from test.support.roibags import small_rig, sway, write_input_bag

JS = REPO / "test" / "js"
NPM_TIMEOUT_S = 180

pytestmark = pytest.mark.skipif(shutil.which("node") is None, reason="node (Node.js) is not installed")


def js_reader() -> Path:
    """A folder with read_bag.mjs and its node_modules, keyed by the lock file's content."""
    lock = (JS / "package-lock.json").read_bytes()
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "roi_node" / "js"
    folder = cache / hashlib.sha256(lock + (JS / "package.json").read_bytes()).hexdigest()[:16]
    if not (folder / "node_modules").is_dir():
        npm = shutil.which("npm")
        assert npm is not None, "node is installed but npm is not: cannot install test/js's packages"
        staging = cache / f".{folder.name}.{os.getpid()}"
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        for name in ("package.json", "package-lock.json"):
            shutil.copy(JS / name, staging / name)
        done = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=staging, capture_output=True, text=True,
                              timeout=NPM_TIMEOUT_S)
        assert done.returncode == 0, f"npm ci failed:\n{done.stderr}"
        if not (folder / "node_modules").is_dir():
            shutil.rmtree(folder, ignore_errors=True)
            staging.rename(folder)  # a half-done install is never taken for a finished one
        else:
            shutil.rmtree(staging, ignore_errors=True)
    shutil.copy(JS / "read_bag.mjs", folder / "read_bag.mjs")
    return folder


def python_view(bag: Path) -> dict[str, Any]:
    """The same summary as read_bag.mjs, read with rosbags."""
    out: dict[str, Any] = {"schemas": {}, "images": {}, "compressed": {}, "markers": {}, "metadata": {}}

    def stamp(header: Any) -> dict[str, int]:
        return {"sec": int(header.stamp.sec), "nanosec": int(header.stamp.nanosec)}

    with AnyReader([bag], default_typestore=typestore()) as reader:
        for connection in reader.connections:
            out["schemas"][connection.topic] = connection.msgtype
        for connection, _, raw in reader.messages():
            msg: Any = reader.deserialize(raw, connection.msgtype)
            topic, kind = connection.topic, connection.msgtype
            if kind == "sensor_msgs/msg/Image":
                value = {"stamp": stamp(msg.header), "frame_id": msg.header.frame_id, "width": int(msg.width),
                         "height": int(msg.height), "encoding": msg.encoding, "sha256": hashlib.sha256(msg.data.tobytes()).hexdigest()}
                out["images"].setdefault(topic, []).append(value)
            elif kind == "sensor_msgs/msg/CompressedImage":
                value = {"stamp": stamp(msg.header), "frame_id": msg.header.frame_id, "format": msg.format,
                         "sha256": hashlib.sha256(msg.data.tobytes()).hexdigest()}
                out["compressed"].setdefault(topic, []).append(value)
            elif kind == "visualization_msgs/msg/ImageMarker":
                value = {"stamp": stamp(msg.header), "frame_id": msg.header.frame_id, "ns": msg.ns, "type": int(msg.type),
                         "points": [[float(p.x), float(p.y)] for p in msg.points]}
                out["markers"].setdefault(topic, []).append(value)
            elif kind == "std_msgs/msg/String":
                record = json.loads(msg.data)
                assert divmod(record["stamp_ns"], 10**9) == (record["stamp"]["sec"], record["stamp"]["nanosec"])
                value = {"stamp": record["stamp"], "crop_boxes": {a["arm_id"]: a["crop_box"] for a in record["arms"]}}
                out["metadata"].setdefault(topic, []).append(value)
    return out


def test_a_foxglove_style_node_reader_decodes_roi_images_the_overlay_and_metadata(tmp_path: Path) -> None:
    rig = small_rig(tmp_path / "rig")
    write_input_bag(tmp_path / "input", rig, sway(4))
    bag = tmp_path / "roi"
    replay_bag(tmp_path / "input", bag, rig, output_transport="both", overlay=True)
    want = python_view(bag)
    folder = js_reader()
    files = sorted(str(p) for p in bag.glob("*.mcap"))
    done = subprocess.run(["node", str(folder / "read_bag.mjs"), *files], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout)
    assert got == want
    # and what was compared is there: an ROI image, its JPEG, a marker with the box corners, a record, per frame
    records = want["metadata"]["/roi/metadata"]
    assert len(records) == 4 and len(want["images"]["/roi/hand/image_raw"]) == 4
    assert len(want["compressed"]["/roi/hand/image_raw/compressed"]) == 4
    markers = got["markers"]["/roi/overlay"]
    for marker, record in zip(markers, records, strict=True):
        assert marker["stamp"] == record["stamp"]
        x0, y0, x1, y1 = record["crop_boxes"]["hand"]
        assert marker["points"][:8] == [[x0, y0], [x1, y0], [x1, y0], [x1, y1], [x1, y1], [x0, y1], [x0, y1], [x0, y0]]
