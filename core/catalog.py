"""Names, choices and ranges of baarda's inputs, shared by the readers, the simulator and the
command line's parser. Light to import (no numpy): ``baarda --help`` builds its parser from them
without loading the computation (issue 30, item 5)."""

from __future__ import annotations

#: the --hypothesis forms of ``baarda test`` (parsed by :func:`baarda.io.hypothesis.parse_hypothesis`)
HYPOTHESIS_SPECS = ("observation:INDEX", "group:G", "image-point:IMAGE:POINT[:KEYPOINT]", "control:POINT",
                    "transfer:POINT:IMAGE,IMAGE,...", "ap-group:CAMERA:brown|ebner", "exchanged:IMAGE:A:B",
                    "model-point:MODEL:POINT", "gnss:IMAGE", "gnss-strip:STRIP", "file:PATH")

#: the cameras of ``baarda simulate --camera``
CAMERAS = {
    "aerial": {"id": "RC30", "c": 153.0, "width": 230.0, "height": 230.0, "unit": "mm"},
    "drone": {"id": "drone", "c": 3650.0, "width": 5472.0, "height": 3648.0, "unit": "px",
              "pixel_size": 0.0024},
}


#: the range of each numeric recipe key: (low, high, integer); a recipe outside them is refused
#: before anything is simulated (a block of 10⁹ strips, an overlap of 1, a height of 10²⁰ m)
RANGES = {
    "strips": (1, 100, True), "images_per_strip": (1, 100, True), "flying_height": (1.0, 1e5, False),
    "forward_overlap": (0.0, 0.95, False), "side_overlap": (0.0, 0.95, False), "relief": (0.0, 1.0, False),
    "attitude_sigma": (0.0, 1.0, False), "position_sigma": (0.0, 1e3, False), "control_spacing": (1, 1000, True),
    "check": (0, 10_000, True), "sigma_image": (1e-9, 1e3, False), "rho": (-0.99, 0.99, False),
    "sigma_control_h": (1e-9, 1e3, False), "sigma_control_v": (1e-9, 1e3, False), "radial": (-1e3, 1e3, False),
    "approx_sigma": (0.0, 1e3, False), "seed": (0, 2**63 - 1, True), "gnss_sigma": (1e-6, 1e3, False),
    "imu_sigma": (1e-9, 10.0, False),
}
