"""Another look for the simulated camera: texture, lighting, sensor noise, motion blur.

Image-based checks must not work only on the default look of the painter,
so a rig can be rendered differently: the surfaces with another texture seed,
a colour cast, a light that falls off across the image and drifts in
brightness over time, per-frame Gaussian sensor noise, and motion blur (the
frame is the mean of several renders spread over the exposure, centred on
the capture time, as a global-shutter camera integrates). The default
`Look()` changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roi_node.engine.errors import ConfigError


@dataclass(frozen=True)
class Look:
    texture_seed: int | None = None  # surfaces from this seed instead of the rig's (objects and layout unchanged)
    colour_cast: tuple[float, float, float] = (1.0, 1.0, 1.0)  # per-channel gain (white balance)
    light_falloff: float = 0.0  # brightness lost from the left edge to the right edge of the image (0..1)
    flicker: float = 0.0  # relative amplitude of a slow brightness drift over time
    noise_sigma: float = 0.0  # grey levels of per-pixel Gaussian noise, fresh every frame
    exposure_ms: float = 0.0  # motion blur: the frame integrates this long around the capture time
    blur_samples: int = 5  # renders averaged over the exposure

    def __post_init__(self) -> None:
        if not (0.0 <= self.light_falloff < 1.0 and 0.0 <= self.flicker < 1.0):
            raise ConfigError(f"sim look: light_falloff and flicker must be in [0, 1), got {self.light_falloff}, {self.flicker}")
        if self.noise_sigma < 0 or self.exposure_ms < 0 or self.blur_samples < 1:
            raise ConfigError("sim look: noise_sigma and exposure_ms must be >= 0 and blur_samples >= 1")

    @property
    def blurred(self) -> bool:
        return self.exposure_ms > 0 and self.blur_samples > 1

    def exposure_offsets_ns(self) -> list[int]:
        """Sample times relative to the capture time, symmetric around it."""
        if not self.blurred:
            return [0]
        half = self.exposure_ms * 1e6 / 2
        return [round(v) for v in np.linspace(-half, half, self.blur_samples)]

    @property
    def default(self) -> bool:
        return self == Look()

    def finish(self, frame: np.ndarray, frame_index: int, t_s: float, seed: int) -> np.ndarray:
        """Lighting and noise over a rendered (possibly blurred, float) frame; uint8 out."""
        out = frame.astype(np.float32) * np.asarray(self.colour_cast, np.float32)
        if self.light_falloff or self.flicker:
            w = out.shape[1]
            ramp = 1.0 - self.light_falloff * np.linspace(0.0, 1.0, w, dtype=np.float32)
            gain = 1.0 + self.flicker * float(np.sin(2 * np.pi * 0.3 * t_s))
            out *= (ramp * gain)[None, :, None]
        if self.noise_sigma:
            rng = np.random.default_rng([seed, frame_index, 0x9015E])
            out += rng.normal(0.0, self.noise_sigma, out.shape).astype(np.float32)
        np.rint(out, out=out)
        return np.clip(out, 0, 255, out=out).astype(np.uint8)
