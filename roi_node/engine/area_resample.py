"""Exact area resampling (OpenCV's INTER_AREA box filter) from a window of the source frame.

OpenCV's INTER_AREA at a non-integer factor gives output pixel d of an axis
the source interval [d*s, (d+1)*s) with s = 1 / (dst/src): every source pixel
it covers weighs its overlap divided by the cell width (the cell is cut at
the image edge), overlaps of at most 1e-3 px are dropped, weights are
float32, sums are float32 and the result rounds half to even. `axis_taps`
builds those weights by that rule, once per (source size, output size);
`resample_window` applies them with the compiled kernel in area_kernels,
reading the window straight from the frame and writing the output's content
region, so neither a padded crop nor a resized intermediate is ever built.
The result stays within one level of cv2.INTER_AREA on the zero-padded crop.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from roi_node.engine import area_kernels


@dataclass(frozen=True)
class AxisTaps:
    """Output d reads source pixels start_px[d] + k, k < offset[d+1] - offset[d], with weight[offset[d] + k]."""

    start_px: np.ndarray  # int64, per output pixel
    offset: np.ndarray  # int64, len = outputs + 1
    weight: np.ndarray  # float32


@lru_cache(maxsize=256)
def axis_taps(src_px: int, dst_px: int) -> AxisTaps:
    """Per-output source runs and weights of area resampling src_px -> dst_px (dst_px <= src_px)."""
    return AxisTaps(*area_kernels.axis_taps(src_px, dst_px))


def resample_window(
    image: np.ndarray, origin_px: tuple[int, int], window_px: tuple[int, int], out: np.ndarray, content_offset_px: tuple[int, int],
    content_px: tuple[int, int],
) -> None:
    """Area-resample the window (origin, width x height; may leave the image) into out's content region only.

    `image` is HxW or HxWxC uint8, `out` is C-contiguous with the same channel count.
    """
    cn = 1 if image.ndim == 2 else image.shape[2]
    src = np.ascontiguousarray(image).reshape(image.shape[0], -1)
    xt = axis_taps(window_px[0], content_px[0])
    yt = axis_taps(window_px[1], content_px[1])
    block = np.empty((area_kernels.BLOCK_ROWS, min(window_px[0], image.shape[1]) * cn), dtype=np.float32)
    area_kernels.area_resample(
        src, cn, int(origin_px[0]), int(origin_px[1]),
        xt.start_px, xt.offset, xt.weight, yt.start_px, yt.offset, yt.weight,
        out.reshape(out.shape[0], -1), int(content_offset_px[0]), int(content_offset_px[1]), block,
    )


def _compile_variants() -> None:
    """Compile (or load from the disk cache) every variant a frame needs.

    One compiled variant serves every channel count; frames arrive writable
    (a live Image buffer) or read-only (a bag message's bytes), which numba
    compiles separately, so both are built.
    """
    for writeable in (True, False):
        image = np.zeros((8, 8, 3), dtype=np.uint8)
        image.flags.writeable = writeable
        out = np.zeros((5, 5, 3), dtype=np.uint8)
        resample_window(image, (-1, -1), (7, 7), out, (0, 0), (5, 5))


class _KernelWarmUp:
    """Compiles the kernels once per process, on a thread of its own, started by whoever needs them.

    Nothing starts it at import: the live node starts it when its stream
    starts (so a pipeline built later, once the URDF or CameraInfo arrives,
    does not stall its callbacks on the JIT), RoiPipeline waits for it, and
    replay waits for it before it counts threads to decide whether it may
    fork its workers. numba serialises compiles, so a frame resampled
    meanwhile just waits for it.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def start(self) -> threading.Thread:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=_compile_variants, name="roi_node-jit-warm-up", daemon=True)
                self._thread.start()
            return self._thread


_KERNELS = _KernelWarmUp()


def start_warm_up() -> None:
    """Start compiling (or loading from the disk cache) the kernels in the background, if not yet started."""
    _KERNELS.start()


def warm_up(timeout_s: float | None = None) -> bool:
    """Compile the kernels (starting that if nobody did) and wait until they are ready; False if `timeout_s`
    passed first. RoiPipeline calls it, so the first frame is not slow."""
    thread = _KERNELS.start()
    thread.join(timeout_s)
    return not thread.is_alive()
