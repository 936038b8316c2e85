"""strip.mp4 (`roi-node demo`'s video): H.264 that browsers play, the global view at the camera's aspect.

Read back with PyAV; the oracle for the global tile is the bag's own global
view resized to the calibration's aspect (640x480: 4:3, a 342 px wide tile).
"""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np

from roi_node.quality.figures.strip import write_strip
from roi_node.wire import topics
from test.support.bagtools import read_decoded, roi_pixels
from test.support.roibags import HEIGHT, WIDTH, roi_bag, small_rig, sway


def test_strip_is_h264_with_the_global_view_at_its_true_aspect(tmp_path: Path) -> None:
    bag = roi_bag(tmp_path, "roi", small_rig(tmp_path), sway(6))
    out = write_strip(bag, ["hand"], tmp_path / "strip.mp4")
    assert out == tmp_path / "strip.mp4"
    global_width = 2 * round(256 * WIDTH / HEIGHT / 2)
    assert global_width == 342
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        decoded = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
    assert len(decoded) == 6
    assert decoded[0].shape == (256, global_width + 256, 3)
    published = roi_pixels(read_decoded(bag, topics.absolute(topics.GLOBAL_IMAGE))[0][2])
    assert published.shape[:2] == (256, 256)  # squashed 4:3 -> 1:1 on the topic; unsquashed in the strip
    expected = cv2.resize(published, (global_width, 256), interpolation=cv2.INTER_LINEAR)
    below_label = slice(30, 256)

    def correlation(a: np.ndarray, b: np.ndarray) -> float:  # of the blurred grey images: geometry, not codec noise
        a, b = (cv2.GaussianBlur(cv2.cvtColor(x[below_label], cv2.COLOR_RGB2GRAY).astype(float), (0, 0), 2.0) for x in (a, b))
        return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])

    unsquashed = correlation(decoded[0][:, :global_width], expected)
    as_published = correlation(decoded[0][:, :256], published)
    assert unsquashed > 0.9 and as_published < 0.5, (unsquashed, as_published)
