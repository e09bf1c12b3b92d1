"""The observation specification, defined once: how noisy each measured channel is and how it
is biased (METHOD.md section 1.3, the paper's synthetic measurements).

``nmt_ros.study.observations`` makes observations with it, and the trackers weigh the
observations by it: the skeletal tracker normalises its contact rows by the force plate's SD
(``SKTSettings``), optimal tracking weighs every channel by its SD
(``OptimalTrackingSettings``). Their settings take their defaults from :data:`OBSERVATION_NOISE`,
so a tracker's weights are the generator's noise by construction, not by copy.

* Segment angles (foot, shank, thigh, HAT): Gaussian noise of SD 5, 3, 2, 1 deg.
* Fore-aft and vertical ground force: SD 2 % of body weight. The ground moment's SD (N m) is
  that force SD times the foot's heel-to-toe length (0.17 m, the data file's contact points):
  the moment of a 2 %-BW force error at the end of the foot, commensurate with the forces (the
  paper gives no unit; 2 % of BW read as N m would be 14.7 N m, 7 % of the peak moment).
* Smooth bias with a peak equal to the channel's SD (shapes in ``study.observations``); the
  ground moment's bias peaks at 20 % of the actual moment's peak.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The bias shapes ``study.observations`` can make ('motion': skin-motion artefact and one
#: force-plate lobe, the default; 'harmonic': a random mix of low harmonics).
BIAS_SHAPES = ('motion', 'harmonic')


@dataclass(frozen=True)
class ObservationNoise:
    """Noise SD per channel and the bias model of the observations."""

    angle_sd_deg: tuple[float, float, float, float] = (5.0, 3.0, 2.0, 1.0)   # foot..HAT
    force_sd_bw: float = 0.02           # fore-aft and vertical force, fraction of body weight
    moment_lever_m: float = 0.17        # moment SD = force SD x this lever (heel-to-toe length)
    moment_bias_fraction: float = 0.20  # moment bias peak / actual moment peak
    bias_shape: str = 'motion'          # one of BIAS_SHAPES
    bias_harmonics: int = 3             # harmonics of the 'harmonic' shape

    def angle_sd_rad(self) -> np.ndarray:
        """Segment-angle SD [4] (rad)."""
        return np.radians(self.angle_sd_deg)

    def wrench_sd(self, body_weight: float) -> np.ndarray:
        """Ground-wrench SD [3]: Fx, Fy (N), moment (N m), for ``body_weight`` (N)."""
        f = self.force_sd_bw
        return np.array([f, f, f * self.moment_lever_m]) * body_weight


#: The paper's observations (METHOD.md 1.3).
OBSERVATION_NOISE = ObservationNoise()
