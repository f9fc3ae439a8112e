"""The sensor catalogue: every stream kind a session may declare, owned by the sensor's own module.

An entry says what a user must write (CSV columns and their units, the session.toml keys with
defaults and meaning), what fusegraph makes of it (the factors) and what loading checks (plausible
magnitudes, unit quaternions, sample times against a declared rate). Each ``factors/<sensor>.py``
module defines its ``CATALOGUE`` entries; ``sensor_catalogue()`` gathers them, ``catalogue_markdown()``
renders ``docs/sensors.md`` and ``fusegraph sensors`` prints it. Adding a sensor = one module with
its entry and factor, plus its tests.

This module imports nothing of the package, so that the factor modules and ``session`` can use it freely
(``sensors.sensor_catalogue`` gathers the entries).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class KeySpec:
    """One session.toml key a stream (or a system) takes."""

    name: str
    """The key as written in session.toml."""
    default: Any
    """Value used when the key is absent (None: absent means 'not used' or 'required', see meaning)."""
    meaning: str
    """What it means, with its unit."""


@dataclass(frozen=True)
class Magnitude:
    """A plausibility check on the norm of each sample (all value columns)."""

    statistic: str
    """``max`` (every sample's norm must stay below ``high``), ``median`` (the median norm must lie in [low, high]) or
    ``still median`` (the same over the samples at rest, ``session.still_norms``: free fall and bouncing are motion, not a
    unit; without a still part it is a warning)."""
    low: float
    """Lowest plausible value (``median`` checks), in the kind's SI unit."""
    high: float
    """Highest plausible value, in the kind's SI unit."""
    likely_cause: str
    """What a violation most likely means, shown in the error (e.g. 'degrees per second?')."""


@dataclass(frozen=True)
class SensorKind:
    """A stream kind: its file format, keys, factors and checks."""

    kind: str
    """Name written as ``kind = ...`` in ``[streams.<name>]``."""
    summary: str
    """One line: what the sensor measures."""
    columns: tuple[str, ...]
    """CSV columns after ``t``, in order."""
    units: tuple[str, ...]
    """Unit of each column (SI, as fusegraph uses it inside)."""
    frame: str
    """The frame the values are expressed in."""
    factors: str
    """The factor(s) a sample becomes, and in which systems."""
    keys: tuple[KeySpec, ...] = ()
    """Keys particular to this kind (the common ones, ``COMMON_KEYS``, apply to every kind)."""
    magnitude: tuple[Magnitude, ...] = ()
    """Plausibility checks on the samples' norms (judged on the declared or SI units)."""
    unit_norm: bool = False
    """Samples are unit quaternions: within 1 % normalised (a warning beyond 1e-6), beyond it an error."""
    unit_conversions: Mapping[str, float] = field(default_factory=dict)
    """``units = ...`` values this kind accepts and their factor to SI (e.g. ``deg/s``: pi/180)."""
    repeated_times: bool = False
    """Several rows may share a sample time (one row per distance heard in an epoch)."""
    nan_columns: tuple[str, ...] = ()
    """Columns that may hold NaN (``missing`` cells), e.g. an optional id."""
    check: Callable[[Any, Mapping[str, Any]], str | None] | None = None
    """Further check of (values, stream keys): a message when implausible, None when fine."""

    def key(self, name: str) -> KeySpec | None:
        for spec in (*COMMON_KEYS, *self.keys):
            if spec.name == name:
                return spec
        return None

    @property
    def key_names(self) -> tuple[str, ...]:
        return tuple(k.name for k in (*COMMON_KEYS, *self.keys))


COMMON_KEYS: tuple[KeySpec, ...] = (
    KeySpec("kind", None, "the stream kind (required): one of the catalogue's kinds"),
    KeySpec("file", "<name>.csv", "CSV file of the stream, relative to the session directory"),
    KeySpec("latency_s", 0.0, "arrival time minus sample time, s (a late sensor's transport delay)"),
    KeySpec("rate_hz", None, "nominal sample rate, Hz; the median sample interval must agree within 2x (gaps stay legal)"),
    KeySpec("frame", None, "free text: the frame the values are in (documentation)"),
    KeySpec("description", None, "free text"),
    KeySpec("role", None, "free text; attitude9 reads role = 'calibration recording' on a mag_cal stream"),
    KeySpec("units", None, "the units the CSV is written in when not SI (see the kind's accepted units); converted on loading"),
    KeySpec("unit", None, "free text: the unit the values are in when the kind leaves it open (the magnetometer)"),
    KeySpec("frame_R_sensor", None, "gyro, accel, mag: the rotation from this stream's axes into the body frame (the gyro's), "
            "3 rows of 3 (a signed permutation for axes swapped or negated); applied on loading, so every solver reads body axes"),
)
"""Keys every stream may carry."""

TRUTH_KEYS: tuple[KeySpec, ...] = (
    KeySpec("kind", "attitude", "kind of the truth stream (attitude, position, ...)"),
    KeySpec("file", "truth.csv", "CSV of the ground truth; NaN rows where it is unknown (occlusions)"),
    KeySpec("frame", None, "free text"),
    KeySpec("world_frame", None, "free text"),
    KeySpec("description", None, "free text"),
    KeySpec("source", None, "free text: where the truth comes from (e.g. optical motion capture)"),
)
"""Keys of the ``[truth]`` table."""


class CatalogueError(ValueError):
    """A key or kind that the catalogue does not know (the message suggests the nearest)."""


def suggest(name: str, known: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the nearest known name, or an empty string."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def check_keys(table: Mapping[str, Any], known: Iterable[str], where: str) -> None:
    """Raise ``CatalogueError`` for the first key of ``table`` not in ``known``, suggesting the nearest."""
    allowed = tuple(known)
    for name in table:
        if name not in allowed:
            raise CatalogueError(f"{where}: unknown key '{name}'{suggest(name, allowed)}; known keys: {', '.join(allowed)}")


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    return f"`{value}`"


def kind_markdown(entry: SensorKind) -> str:
    """One kind's section of ``docs/sensors.md``."""
    lines = [f"## `{entry.kind}`", "", entry.summary, ""]
    columns = ", ".join(f"`{c}` [{u}]" for c, u in zip(entry.columns, entry.units, strict=True))
    lines.append(f"- CSV columns: `t` [s, sample time]{', ' if columns else ''}{columns}")
    if entry.repeated_times:
        lines.append("- several rows may share one `t` (one row per value of an epoch)")
    lines.append(f"- frame: {entry.frame}")
    lines.append(f"- becomes: {entry.factors}")
    checks = [f"{m.statistic} norm in [{m.low:g}, {m.high:g}] ({m.likely_cause})" for m in entry.magnitude]
    if entry.unit_norm:
        checks.append("unit quaternion (within 1 %: normalised, beyond: an error)")
    if checks:
        lines.append("- loading checks: " + "; ".join(checks))
    if entry.unit_conversions:
        lines.append("- accepted `units`: " + ", ".join(f"`{u}`" for u in entry.unit_conversions))
    lines += ["", "| key | default | meaning |", "|---|---|---|"]
    for spec in entry.keys:
        lines.append(f"| `{spec.name}` | {_cell(spec.default)} | {spec.meaning} |")
    lines.append(f"| (common) | | {', '.join(f'`{k.name}`' for k in COMMON_KEYS)} |")
    return "\n".join(lines) + "\n"


def check_sensors(system: str, sensors: Iterable[str], required: Iterable[str], optional: Iterable[str]) -> tuple[str, ...]:
    """A simulation's ``--sensors`` list checked against what the system needs and can add; returned as a tuple."""
    given, needed, allowed = tuple(sensors), set(required), set(required) | set(optional)
    unknown = sorted(set(given) - allowed)
    if unknown or not needed <= set(given):
        raise ValueError(f"{system} sensors {','.join(given)}: {', '.join(sorted(needed))} required, {', '.join(sorted(set(optional)))} optional "
                         f"(unknown: {', '.join(unknown) or '-'})")
    return given
