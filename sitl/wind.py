"""Wind: a constant mean plus first-order Gauss-Markov gusts (pure numpy).

Each ENU gust component g follows the first-order Gauss-Markov process (the first-order shaping
filter that Dryden-type turbulence models reduce to when driven by time instead of distance):

    dg/dt = -g / T + sigma * sqrt(2 / T) * white noise

discretised exactly for a step dt:  g <- a g + sigma sqrt(1 - a^2) n,  a = exp(-dt / T),  n ~ N(0, 1).
The process starts in its stationary distribution (g_0 ~ N(0, sigma^2)), so its standard deviation is
sigma at every time. Same seed, same sequence of dt -> same wind.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from sitl.config import WindConfig

logger = logging.getLogger(__name__)


class WindModel:
    def __init__(self, cfg: WindConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng
        self._mean = np.array(cfg.mean_velocity_enu_m_s, dtype=float)
        self._sigma = float(cfg.gust_std_m_s)
        self._tau = float(cfg.gust_time_constant_s)
        self._gust = self._sigma * rng.standard_normal(3) if self._sigma > 0.0 else np.zeros(3)
        self._cache_dt_s = -1.0
        self._a = 1.0
        self._b = 0.0

    @property
    def gust_enu_m_s(self) -> np.ndarray:
        """Current gust (deviation from the mean), m/s."""
        return self._gust.copy()

    def velocity_enu_m_s(self, dt_s: float) -> np.ndarray:
        """Advance the gusts by ``dt_s`` (s, >= 0) and return the wind velocity (ENU, m/s)."""
        if dt_s < 0.0:
            raise ValueError(f"dt_s = {dt_s}: expected a number >= 0")
        if self._sigma > 0.0 and dt_s > 0.0:
            if dt_s != self._cache_dt_s:
                self._cache_dt_s = dt_s
                self._a = math.exp(-dt_s / self._tau)
                self._b = self._sigma * math.sqrt(-math.expm1(-2.0 * dt_s / self._tau))
            self._gust = self._a * self._gust + self._b * self._rng.standard_normal(3)
        return self._mean + self._gust
