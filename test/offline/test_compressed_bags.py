"""ROI bags with compressed outputs and the overlay (`replay --output-transport`, `--overlay`), read by every ROI-bag reader.

The oracle is an independent read with rosbags' AnyReader and cv2.imdecode of
the bag's CompressedImage data, and the raw-output replay of the same input.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from roi_node.bagio.reader import stamp_ns
from roi_node.bagio.writer import typestore
from roi_node.cli import main
from roi_node.offline.replay import replay_bag
from roi_node.quality.roibag import RoiBag, roi_image_topic
from test.datasets.test_export import decode, frames_table
from test.support.exportbags import ExportBags, images_by_stamp, psnr_db, records_by_stamp
from test.wire.test_overlay import box_edges

ARMS = ("left", "right")
MIN_PSNR_DB = 30.0  # JPEG tolerance at quality 90 on the simulated rig's frames


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A recording, and it replayed twice: raw outputs, and compressed outputs (q90) with the overlay."""
    recordings = ExportBags(tmp_path_factory.mktemp("sim"))
    source = recordings.raw(0)
    out = tmp_path_factory.mktemp("roi")
    replay_bag(source, out / "raw", recordings.rig)
    replay_bag(source, out / "jpeg", recordings.rig, output_transport="compressed", jpeg_quality=90, overlay=True)
    return source, out / "raw", out / "jpeg"


def read(bag: Path, topic: str) -> list[Any]:
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)]


def jpeg_images(bag: Path, topic: str) -> dict[int, np.ndarray]:
    out = {}
    for msg in read(bag, topic):
        assert msg.format == "rgb8; jpeg compressed bgr8"
        out[stamp_ns(msg.header)] = cv2.cvtColor(cv2.imdecode(np.asarray(msg.data), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out


def test_compressed_replay_has_the_nodes_topics_and_images_within_jpeg_tolerance(bags: tuple[Path, Path, Path]) -> None:
    _, raw, jpeg = bags
    with RoiBag(jpeg) as bag:
        names = set(bag.topics)
        records = list(bag.records())
        for arm in ARMS:
            assert bag.topics[f"/roi/{arm}/image_raw/compressed"].msgtype == "sensor_msgs/msg/CompressedImage"
            assert f"/roi/{arm}/image_raw" not in names
        # RoiBag.image finds the compressed topic for the raw name and decodes it
        sample = records[len(records) // 2]
        via_roibag = bag.image(roi_image_topic("left"), sample.log_ns, sample.record.stamp_ns)
    assert "/roi/global/image_raw/compressed" in names and "/roi/global/image_raw" not in names
    assert records_by_stamp(jpeg) == records_by_stamp(raw)
    for topic in ["/roi/global/image_raw"] + [f"/roi/{arm}/image_raw" for arm in ARMS]:
        want, got = images_by_stamp(raw, topic), jpeg_images(jpeg, topic + "/compressed")
        assert sorted(got) == sorted(want) and len(got) == len(records)
        assert min(psnr_db(want[s], got[s]) for s in want) >= MIN_PSNR_DB
    assert via_roibag is not None
    assert np.array_equal(via_roibag, jpeg_images(jpeg, "/roi/left/image_raw/compressed")[sample.record.stamp_ns])


def test_the_overlay_in_a_replayed_bag_draws_each_records_crop_box(bags: tuple[Path, Path, Path]) -> None:
    _, _, jpeg = bags
    records = records_by_stamp(jpeg)
    markers = read(jpeg, "/roi/overlay")
    assert sorted(stamp_ns(m.header) for m in markers) == sorted(records)
    for marker in markers:
        record = records[stamp_ns(marker.header)]
        assert marker.header.frame_id != "" and marker.type == 2  # LINE_LIST
        points = [(float(p.x), float(p.y)) for p in marker.points]
        segments = {(points[i], points[i + 1]) for i in range(0, len(points), 2)}
        for arm in record["arms"]:
            assert box_edges(arm["crop_box"]) <= segments


def test_a_lossless_export_of_the_compressed_bag_shows_its_decoded_jpegs(bags: tuple[Path, Path, Path], tmp_path: Path) -> None:
    _, _, jpeg = bags
    out = tmp_path / "dataset"
    assert main(["export", "lerobot", str(jpeg), "-o", str(out), "--fps", "15", "--task", "t", "--codec", "lossless"]) == 0
    truth = jpeg_images(jpeg, "/roi/right/image_raw/compressed")
    stamps = frames_table(out)["roi_node.source_stamp_ns"]
    decoded = decode(out / "videos/observation.images.roi_right/chunk-000/file-000.mp4")
    assert len(decoded) == len(stamps) == len(set(stamps)) >= len(truth) - 1  # the grid may end before the last frame
    assert all(np.array_equal(image, truth[stamps[i]]) for i, (_, image) in enumerate(decoded))


def test_bad_output_options_are_refused_in_one_line(bags: tuple[Path, Path, Path], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    source = bags[0]
    code = main(["replay", str(source), "-o", str(tmp_path / "out"), "--config", str(ExportBags(tmp_path).rig),
                 "--output-transport", "compressed", "--jpeg-quality", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "JPEG quality must be in 1..100, got 0" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
