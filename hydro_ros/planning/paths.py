"""Prescribed tip paths (P-V Section 6.1, P-VI Section 6): quintic rest-to-rest lines and clamped splines.

A path is a chain of segments from ``start``; each segment ends at rest. Quintic segments follow
s = 10 tau^3 - 15 tau^4 + 6 tau^5 (peak speed 1.875 |B - A| / T); spline segments are cubic
splines through via points, clamped to zero velocity at both ends, with knot times in proportion
to the chord lengths (INFERRED: P-VI cites Biagiotti & Melchiorri without the knot rule).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline

from hydro_ros.contract.config import ConfigError
from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import InputError


@dataclass(frozen=True)
class PathSamples:
    """Tip position, velocity and acceleration (N+1, 3) at t_k = k T_s."""

    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    @property
    def stages(self) -> int:
        return len(self.time) - 1

    def at(self, k: int) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        return tuple(self.position[k]), tuple(self.velocity[k]), tuple(self.acceleration[k])


class _Segment:
    def __init__(self, start: np.ndarray, spec: dict[str, Any]) -> None:
        self.kind = str(spec.get("type", "quintic"))
        self.duration = float(spec["duration"])
        if self.duration <= 0.0:
            raise InputError("segment duration must be positive")
        self.start = start
        self.end = np.asarray(spec["to"], dtype=float)
        if self.kind == "quintic":
            self._spline = None
        elif self.kind == "spline":
            points = np.vstack([start, np.asarray(spec.get("via", []), dtype=float).reshape(-1, 3), self.end])
            chords = np.linalg.norm(np.diff(points, axis=0), axis=1)
            knots = np.concatenate([[0.0], np.cumsum(chords)]) / chords.sum() * self.duration
            self._spline = CubicSpline(knots, points, bc_type="clamped", axis=0)
        else:
            raise InputError(f"segment type {self.kind!r} (quintic or spline)")

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.clip(t, 0.0, self.duration)
        if self._spline is not None:
            return self._spline(t), self._spline(t, 1), self._spline(t, 2)
        tau = (t / self.duration)[:, None]
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        s_d = 30.0 * tau**2 * (1.0 - tau) ** 2 / self.duration
        s_dd = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / self.duration**2
        delta = self.end - self.start
        return self.start + s * delta, s_d * delta, s_dd * delta


class TipPath:
    """A path of a crane config's ``paths:`` section."""

    def __init__(self, path_id: str, spec: dict[str, Any]) -> None:
        self.path_id = path_id
        self.description = str(spec.get("description", ""))
        try:
            point = np.asarray(spec["start"], dtype=float)
            if point.shape != (3,):
                raise InputError("start must be [x, y, z]")
            self.segments: list[_Segment] = []
            for segment_spec in spec["segments"]:
                segment = _Segment(point, segment_spec)
                if segment.end.shape != (3,):
                    raise InputError("segment 'to' must be [x, y, z]")
                self.segments.append(segment)
                point = segment.end
        except KeyError as exc:
            raise ConfigError(f"path {path_id}: missing {exc.args[0]!r} (start [x, y, z]; segments, each a type quintic or spline, "
                              "to [x, y, z], duration [s], a spline's via points)") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"path {path_id}: {exc}") from None
        if not self.segments:
            raise ConfigError(f"path {path_id}: no segments")
        self.duration = sum(segment.duration for segment in self.segments)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration (len(t), 3) at times t (s from the path start)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = [np.zeros((len(t), 3)) for _ in range(3)]
        begin = 0.0
        for index, segment in enumerate(self.segments):
            last = index == len(self.segments) - 1
            mask = (t >= begin) & ((t <= begin + segment.duration) if last else (t < begin + segment.duration))
            if index == 0:
                mask |= t < begin
            if last:
                mask |= t > begin + segment.duration
            if mask.any():
                for target, value in zip(out, segment.evaluate(t[mask] - begin)):
                    target[mask] = value
            begin += segment.duration
        return out[0], out[1], out[2]

    def sample(self, sample_time: float) -> PathSamples:
        stages = int(round(self.duration / sample_time))
        if abs(stages * sample_time - self.duration) > 1e-9 * self.duration:
            raise ConfigError(f"path {self.path_id}: duration {self.duration} s is not a multiple of T_s = {sample_time} s")
        time = np.arange(stages + 1) * sample_time
        return PathSamples(time, *self.evaluate(time))


def path_from_config(config: CraneConfig, path_id: str) -> TipPath:
    return TipPath(path_id, config.path(path_id))
