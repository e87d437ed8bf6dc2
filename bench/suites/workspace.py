"""Where the suites work by default: the paper's square (accuracy) and the ISO 9283 test cube with
its five poses (repeatability). Shared here so no suite imports another's constants (the EEPROM
wear trial of startup-recovery drives both)."""

from __future__ import annotations

from typing import Final

__all__ = ["CYCLE_ORDER", "DEFAULT_CUBE_CENTRE_M", "DEFAULT_CUBE_SIDE_M",
           "DEFAULT_SQUARE_CENTRE_M", "DEFAULT_SQUARE_SIDE_M", "POSE_NAMES"]

#: Default square: centre (m) in front of the arm, elbow up, every edge point ≥ 3° inside the
#: joint limits on the ``front-up`` branch; side (m).
DEFAULT_SQUARE_CENTRE_M: Final = (0.38, 0.0, 0.80)
DEFAULT_SQUARE_SIDE_M: Final = 0.15
#: Names of the five ISO poses, rows 0..4 of ``iso_cube_poses``.
POSE_NAMES: Final = ("P1", "P2", "P3", "P4", "P5")
#: ISO 9283's cycle order.
CYCLE_ORDER: Final = ("P1", "P5", "P4", "P3", "P2")
#: Default test cube: centre (m) and side (m), chosen so every pose and approach point is ≥ 9°
#: inside the joint limits on the front-up branch.
DEFAULT_CUBE_CENTRE_M: Final = (0.35, 0.0, 0.82)
DEFAULT_CUBE_SIDE_M: Final = 0.10
