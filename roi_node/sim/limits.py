"""The simulator's accepted ranges, shared by its verbs' parsers and kept free of heavy imports (the CLI loads it to register).

Each bound keeps a value the simulator turns into nanosecond stamps, frame
counts or message fields representable, so an absurd one is refused by the
parser in one line instead of overflowing deep inside a run.
"""

from __future__ import annotations

MAX_SIM_DURATION_S = 86_400.0  # a day of simulated time
MAX_SIM_RATE_HZ = 1_000.0  # camera and joint state rates; the joint stamps' 0.3 ms jitter needs a period above 0.6 ms
MAX_SIM_CAMERA_DELAY_MS = 10_000.0  # the rig loader's bound for camera.delay_ms (engine/config.py MAX_TIME_MS)
MAX_SIM_RENDER_BUDGET_MIB = 1_048_576.0  # 1 TiB: more than any machine renders ahead; beyond it the byte count overflows
MAX_JOINT_SPEED_RAD_S = 100.0  # --max-joint-speed-rad-s: far above any arm's joint speed, keeps a step's size finite
DEFAULT_MAX_JOINT_SPEED_RAD_S = 1.0  # about a cobot's reduced-speed joint limit; m/s for prismatic fingers
