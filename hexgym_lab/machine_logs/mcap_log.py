"""Machine logs from ROS 2 bags recorded as MCAP (``ros2 bag record -s mcap``, the default storage since Iron), read
with ``mcap`` and ``mcap-ros2-support`` (the optional extra ``hexgym[logs]``), through a mapping file (YAML)::

    time: log_time              # or header: each message's header.stamp (default: log_time)
    clock: /joint_states        # the topic whose stamps are the log's time base (default: the one with most messages)
    pilot: {start_pa: 0.5e6, full_pa: 3.0e6}     # the pilot -> spool map, where the log has pilots (optional)
    signals:                    # a signal of the format: its topic and field (a dotted path, [i] for an element)
      q_boom_rad: {topic: /joint_states, field: "position[1]"}
      boom_head_pressure_pa: {topic: /pressures, field: boom_head, scale: 1.0e5}   # value * scale + offset

Each signal is read at its own topic's stamps and interpolated (linearly) onto the clock topic's; where its topic
is silent for more than :data:`GAP_PERIODS` of its periods, or before its first / after its last message, the
signal is NaN, so a topic's gap shows as that signal's NaN run. Each topic's stamps, in the file's order, are kept
in :attr:`MachineLog.clocks` for the time checks. ROS 2's older SQLite bags (``.db3``) are not read: convert them
with ``ros2 bag convert`` to MCAP.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.checks import parse_float
from hexgym.files import check_input_file
from hexgym_lab.machine_logs.signals import PILOT_FULL_PA, PILOT_START_PA, SIGNALS, TIME, MachineLog

GAP_PERIODS = 5.0  # a topic silent for longer than this many of its median periods has a gap
_KEYS = {"time", "clock", "pilot", "signals"}
_SIGNAL_KEYS = {"topic", "field", "scale", "offset"}
_PATH = re.compile(r"[A-Za-z_]\w*(\[\d+\])?(\.[A-Za-z_]\w*(\[\d+\])?)*")


def _extra_missing() -> str:
    return "reading MCAP needs the optional extra: pip install 'hexgym[logs]' (mcap, mcap-ros2-support)"


def read_mapping(path: str | Path) -> dict[str, Any]:
    """A mapping file (YAML), checked: ValueError naming the file and the key of the first problem."""
    path = check_input_file(path, "mapping file")
    try:
        import yaml
    except ImportError:
        raise ValueError(f"{path}: reading a mapping file needs PyYAML: pip install 'hexgym[logs]'") from None
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not readable YAML ({' '.join(str(exc).split())[:120]})") from None
    return check_mapping(data, str(path))


def check_mapping(data: Any, source: str) -> dict[str, Any]:
    """A mapping's content checked (see the module); ValueError naming ``source`` and the key."""
    if not isinstance(data, Mapping) or not isinstance(data.get("signals"), Mapping) or not data["signals"]:
        raise ValueError(f"{source}: a mapping needs 'signals:', each signal's topic and field")
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise ValueError(f"{source}: unknown key {unknown[0]!r}; the keys are {', '.join(sorted(_KEYS))}")
    if data.get("time", "log_time") not in ("log_time", "header"):
        raise ValueError(f"{source}: time must be log_time or header, got {data['time']!r}")
    for name, spec in data["signals"].items():
        _check_signal(source, name, spec)
    pilot = data.get("pilot") or {}
    if not isinstance(pilot, Mapping) or set(pilot) - {"start_pa", "full_pa"}:
        raise ValueError(f"{source}: pilot must be a mapping with start_pa and full_pa")
    pilot = {key: _finite(source, f"pilot.{key}", value) for key, value in pilot.items()}
    if pilot.get("full_pa", PILOT_FULL_PA) <= pilot.get("start_pa", PILOT_START_PA):
        raise ValueError(f"{source}: pilot.full_pa must be above pilot.start_pa")
    signals = {name: dict(spec) for name, spec in data["signals"].items()}
    for name, spec in signals.items():
        for key in ("scale", "offset"):
            if key in spec:
                spec[key] = _finite(source, f"signals.{name}.{key}", spec[key])
    return dict(data) | {"pilot": pilot, "signals": signals}


def _check_signal(source: str, name: str, spec: Any) -> None:
    where = f"{source}: signals.{name}"
    if name not in SIGNALS or name == TIME:
        raise ValueError(f"{where}: not a signal of the machine-log format (docs/machine-logs.md lists them)")
    if not isinstance(spec, Mapping) or not {"topic", "field"} <= set(spec) or set(spec) - _SIGNAL_KEYS:
        raise ValueError(f"{where}: give topic and field (and optionally scale, offset)")
    if not isinstance(spec["field"], str) or not _PATH.fullmatch(spec["field"]):
        raise ValueError(f"{where}: field {spec['field']!r} is not a field path like 'position[1]' or 'a.b'")


def _finite(source: str, key: str, value: Any) -> float:
    """A finite number, or one written as text (YAML 1.1 reads ``1.0e5`` as a string); ValueError naming the key."""
    if isinstance(value, str):
        value = _text_number(value)
    if not isinstance(value, numbers.Real) or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{source}: {key} must be a finite number, got {value!r}")
    return float(value)


def _text_number(text: str) -> float | str:
    try:
        return parse_float(text)
    except ValueError:
        return text


def _field(message: Any, path: str) -> float:
    """The value at a field path (``a.b[2]``) of a decoded message, as a float (NaN where it is missing)."""
    value = message
    try:
        for part in path.split("."):
            name, _, index = part.partition("[")
            value = getattr(value, name)
            if index:
                value = value[int(index[:-1])]
        return float(value)
    except (AttributeError, IndexError, TypeError, ValueError):
        return math.nan


def _stamp(message: Any, decoded: Any, use_header: bool) -> float:
    if not use_header:
        return message.log_time * 1e-9
    stamp = getattr(getattr(decoded, "header", None), "stamp", None)
    return math.nan if stamp is None else stamp.sec + stamp.nanosec * 1e-9


def _read_topics(path: Path, mapping: dict[str, Any]) -> dict[str, dict[str, list[float]]]:
    """Per topic: its stamps (``"t"``) and each mapped signal's raw values, in the file's order."""
    try:
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory
    except ImportError:
        raise ValueError(f"{path}: {_extra_missing()}") from None
    signals = mapping["signals"]
    topics = {spec["topic"] for spec in signals.values()}
    out = {topic: {"t": []} | {n: [] for n, s in signals.items() if s["topic"] == topic} for topic in topics}
    use_header = mapping.get("time", "log_time") == "header"
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=list(topics), log_time_order=False):
            columns = out[channel.topic]
            columns["t"].append(_stamp(message, decoded, use_header))
            for name in columns.keys() - {"t"}:
                columns[name].append(_field(decoded, signals[name]["field"]))
    return out


def read_mcap_log(path: str | Path, mapping: dict[str, Any] | str | Path) -> MachineLog:
    """A machine log from an MCAP file through a mapping (its path or checked content, see the module)."""
    path = check_input_file(path, "machine log")
    mapping = read_mapping(mapping) if isinstance(mapping, str | Path) else mapping
    try:
        topics = _read_topics(path, mapping)
    except ValueError:
        raise
    except Exception as exc:  # the reader's own errors: a file that is not MCAP, a truncated one, a bad schema
        raise ValueError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None
    empty = sorted(t for t, c in topics.items() if not c["t"])
    if empty:
        raise ValueError(f"{path}: topic {empty[0]} has no messages (the mapping names it)")
    clock = mapping.get("clock") or max(topics, key=lambda topic: len(topics[topic]["t"]))
    if clock not in topics:
        raise ValueError(f"{path}: clock topic {clock} is not one the mapping's signals come from")
    t = np.array(topics[clock]["t"])
    signals: dict[str, np.ndarray] = {}
    for topic, columns in topics.items():
        stamps = np.array(columns["t"])
        for name in columns.keys() - {"t"}:
            spec = mapping["signals"][name]
            raw = np.array(columns[name]) * spec.get("scale", 1.0) + spec.get("offset", 0.0)
            signals[name] = raw if topic == clock else resample(stamps, raw, t)
    clocks = {f"clock {topic}": np.array(c["t"]) for topic, c in topics.items() if topic != clock}  # t is clock's
    pilot = mapping.get("pilot") or {}
    pilot_pa = (pilot.get("start_pa", PILOT_START_PA), pilot.get("full_pa", PILOT_FULL_PA))
    return MachineLog(str(path), t, signals, clocks=clocks, pilot_pa=pilot_pa)


def resample(stamps: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``values`` at ``stamps`` interpolated linearly onto ``t``; NaN outside the stamps and across their gaps
    (an interval longer than :data:`GAP_PERIODS` median periods)."""
    order = np.argsort(stamps, kind="stable")
    s, v = stamps[order], values[order]
    good = np.isfinite(s)
    s, v = s[good], v[good]
    if len(s) < 2:
        return np.full(len(t), np.nan)
    out = np.interp(t, s, v)
    i = np.clip(np.searchsorted(s, t), 1, len(s) - 1)
    period = float(np.median(np.diff(s)))
    gap = (s[i] - s[i - 1]) > GAP_PERIODS * max(period, 1e-9)
    out[(t < s[0]) | (t > s[-1]) | gap | ~np.isfinite(t)] = np.nan
    return out
