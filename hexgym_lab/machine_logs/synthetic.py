"""A reference run written as a machine log: what a retrofitted machine's logger would have recorded of it.

The reference's rows (every step, :data:`hexgym.hydraulics.reference.TRAJECTORY_COLUMNS`) carry the spools, the
pump and chamber pressures and the joint angles under the format's own names; they are interpolated (linearly)
onto the logger's sample times and given Gaussian sensor noise. Sample times: ``k / rate`` for k = 0, 1, ... up to
the run's end, each moved by ``jitter`` times a period times a uniform draw in [-1/2, 1/2] (a logger's scheduling;
``jitter`` < 1 keeps them ascending). The engine speed is the rated one (the reference's engine holds it) and the
payload the run's. Everything random comes from one ``numpy`` generator seeded with ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexgym.machine import parameters as p
from hexgym_lab.machine_logs import signals as s

# Default sensor noise (standard deviations): pressure transducers of 0-60 MPa at ~0.3 % of span, absolute
# encoders on the joints of ~0.1 deg, spool LVDTs none (the commands are exact) [est: industrial sensors of the
# class, e.g. 0.25-0.5 % FS pressure transducers and 14-bit inclinometers / encoders].
DEFAULT_NOISE = {"pressure_pa": 0.2e6, "angle_rad": float(np.radians(0.1)), "spool_mm": 0.0}
LOGGED = (*s.SPOOLS, *s.PUMP_PRESSURES, *s.CHAMBER_PRESSURES, *s.JOINT_ANGLES)


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the sensors' Gaussian noise, per kind of signal."""

    pressure_pa: float = DEFAULT_NOISE["pressure_pa"]
    angle_rad: float = DEFAULT_NOISE["angle_rad"]
    spool_mm: float = DEFAULT_NOISE["spool_mm"]

    def sigma(self, name: str) -> float:
        """The noise of signal ``name``."""
        if name in s.PRESSURES:
            return self.pressure_pa
        if name in s.JOINT_ANGLES:
            return self.angle_rad
        return self.spool_mm if name in s.SPOOLS else 0.0


def parse_noise(text: str, option: str = "--sensor-noise") -> SensorNoise:
    """``"default"``, ``"off"`` or ``kind=sigma,...`` (kinds ``pressure_pa``, ``angle_rad``, ``spool_mm``; the rest
    their defaults); ValueError naming the option and the part."""
    text = text.strip()
    if text == "default":
        return SensorNoise()
    if text == "off":
        return SensorNoise(0.0, 0.0, 0.0)
    values = dict(DEFAULT_NOISE)
    for part in text.split(","):
        kind, eq, number = part.partition("=")
        kind = kind.strip()
        if not eq or kind not in DEFAULT_NOISE:
            raise ValueError(f"{option} {text!r}: {part!r} is not kind=sigma with a kind of {', '.join(DEFAULT_NOISE)}"
                             " (or give 'default' or 'off')")  # fmt: skip
        try:
            sigma = float(number)
        except ValueError:
            sigma = -1.0
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"{option} {text!r}: {kind} must be a finite number >= 0, got {number.strip()!r}")
        values[kind] = sigma
    return SensorNoise(**values)


def sample_times(duration: float, rate_hz: float, jitter: float, rng: np.random.Generator) -> np.ndarray:
    """The logger's sample times over [0, ``duration``] s (see the module)."""
    t = np.arange(int(np.floor(duration * rate_hz + 1e-9)) + 1) / rate_hz
    if jitter > 0:
        t = t + jitter * (rng.random(len(t)) - 0.5) / rate_hz
    return np.clip(t, 0.0, duration)


def machine_log_of(
    rows: np.ndarray,
    rate_hz: float = 100.0,
    noise: SensorNoise | None = None,
    jitter: float = 0.0,
    seed: int = 0,
    payload_kg: float = 0.0,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A reference run's rows (fine, ascending ``t``) as a machine log: its sample times and signals."""
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"--rate must be a finite number > 0 Hz, got {rate_hz!r}")
    if not 0.0 <= jitter < 1.0:
        raise ValueError(f"--jitter must be from 0 to below 1 (a share of the sample period), got {jitter!r}")
    noise = SensorNoise() if noise is None else noise
    rng = np.random.default_rng(seed)
    t = sample_times(float(rows["t"][-1]), rate_hz, jitter, rng)
    signals = {}
    for name in LOGGED:
        clean = np.interp(t, rows["t"], rows[name])
        sigma = noise.sigma(name)
        signals[name] = clean + sigma * rng.standard_normal(len(t)) if sigma > 0 else clean
    signals[s.ENGINE_SPEED] = np.full(len(t), p.ENGINE_SPEED * 60.0 / (2.0 * np.pi))
    signals[s.PAYLOAD] = np.full(len(t), float(payload_kg))
    return t, signals
