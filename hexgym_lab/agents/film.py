"""The films' caption: one overlay on every frame ``hexgym demo``, ``hexgym video`` and ``hexgym plan --video`` write.

Each frame of a loading site gets a dark strip across its top with the episode's time, the loading phase the
machine is in, the tonnes in the bucket, the tonnes delivered to the truck and the fuel burnt (from the step's
``info``, :data:`hexgym.envs.task.INFO_STORES`). The phase is the one the scripted loader reads off the state
(:func:`hexgym.agents.scripted.infer_phase`): a function of the state alone, so it labels any policy's film alike.
The text is drawn with Pillow (which imageio brings), in fixed columns so that changing figures do not jitter.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any

import numpy as np

PHASE_NAMES = {
    "to_pile": "to pile", "penetrate": "penetrate", "drag": "dig", "curl": "curl", "to_truck": "to truck",
    "dump": "dump",
}  # fmt: skip
# each column's widest text: it reserves the column's width, so the columns stay put while the figures change
_COLUMNS = ("t 000.0 s", "phase penetrate", "bucket 0.00 t", "delivered 00.00 t", "fuel 00.00 L")
_GAP = "   "  # between columns
_MIN_FONT_PX, _FONT_SHARE = 9, 1 / 32  # the text's height: this share of the frame's, at least this many px
STRIP_SHADE = 0.6  # how much the strip darkens the scene behind it


def phase_of(env: Any) -> str:
    """The loading phase (a :data:`PHASE_NAMES` value) the state of ``env`` (a loading site) is in."""
    from hexgym.agents.scripted import LoaderState, infer_phase

    site = env.unwrapped
    phase = infer_phase(LoaderState.of(site), site.layout)
    return PHASE_NAMES.get(phase, phase)


def caption(info: dict[str, Any], phase: str, label: str = "", note: str = "") -> list[tuple[str, str]]:
    """The caption of a step's ``info``: [``label``,] time, phase, bucket, delivered, fuel[, ``note``], each column
    as (its text, the widest text it takes: the column's width); a task without a truck (``HexDig-v0``) or fuel in
    its ``info`` leaves that column out."""
    fields = [
        f"t {info['time_s']:.1f} s", f"phase {phase}", f"bucket {info['bucket_kg'] / 1000:.2f} t",
        f"delivered {info['truck_kg'] / 1000:.2f} t" if "truck_kg" in info else None,
        f"fuel {info['fuel_l']:.2f} L" if "fuel_l" in info else None,
    ]  # fmt: skip
    columns = [(shown, widest) for shown, widest in zip(fields, _COLUMNS, strict=True) if shown is not None]
    return [(label, label)] * bool(label) + columns + [(note, note)] * bool(note)


def film_frame(env: Any, info: dict[str, Any], label: str = "", note: str = "") -> np.ndarray:
    """``env``'s rendered frame with the caption of the step whose ``info`` is given (:func:`caption`)."""
    return overlay_text(env.render(), caption(info, phase_of(env), label, note))


def overlay_text(frame: np.ndarray, text: str | Sequence[str | tuple[str, str]]) -> np.ndarray:
    """``frame`` with ``text`` in white on a dark strip across its top: a string, or columns (strings, or pairs of
    a text and the widest text its column takes, as :func:`caption` gives).

    Returns a new uint8 array; only the strip's rows change. The font scales with the frame's height and shrinks
    to fit its width.
    """
    from PIL import Image, ImageDraw

    columns = [(c, c) if isinstance(c, str) else c for c in ([text] if isinstance(text, str) else text)]
    height, width = frame.shape[:2]
    size = max(_MIN_FONT_PX, round(height * _FONT_SHARE))
    font = _font(size)
    needed = _span(font, columns)
    if needed > width - size and size > _MIN_FONT_PX:
        size = max(_MIN_FONT_PX, int(size * (width - size) / needed))
        font = _font(size)
    strip = min(height, round(size * 1.7))
    out = frame.copy()
    out[:strip] = (out[:strip] * (1.0 - STRIP_SHADE)).astype(np.uint8)
    image = Image.fromarray(out[:strip])
    draw = ImageDraw.Draw(image)
    x, gap = size / 2, font.getlength(_GAP)
    for shown, widest in columns:
        draw.text((x, (strip - size) / 2), shown, fill=(255, 255, 255), font=font)
        x += max(font.getlength(shown), font.getlength(widest)) + gap
    out[:strip] = np.asarray(image)
    return out


def _span(font: Any, columns: Sequence[tuple[str, str]]) -> float:
    """Width (px) of ``columns`` in ``font``, gaps included."""
    widths = [max(font.getlength(shown), font.getlength(widest)) for shown, widest in columns]
    return sum(widths) + font.getlength(_GAP) * (len(columns) - 1)


@cache
def _font(size: int) -> Any:
    """Pillow's built-in font at ``size`` px (its bitmap font where Pillow is older than 10.1)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one size only
        return ImageFont.load_default()
