"""The settings chosen by ``fusegraph tune`` (``tuned.toml`` beside this module, shipped in the package).

Every free setting of a baseline that its paper does not fix, and every free setting of our graphs,
is chosen by one rule (``fusegraph.evaluation.tuning``: a stated grid on tuning seeds 100-119, or
leave-one-trial-out on the BROAD recordings) and written here by ``fusegraph tune STUDY --write``.
The code reads its defaults from this file, so a report always runs with what the last study chose,
and the file says on what (``seeds`` or ``trials``) and with what score.
"""

from __future__ import annotations

import functools
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

TUNED_PATH = Path(__file__).with_name("tuned.toml")
"""The file (in the package, next to this module)."""

HEADER = (
    "# Settings chosen by `fusegraph tune STUDY --write` (one rule for every method: a grid on tuning seeds 100-119,\n"
    "# or leave-one-trial-out on the BROAD recordings). Read by the reports and benches; edit by re-running the study.\n"
    "# Per study: the chosen values, then what they were chosen on (seeds or trials), the score and its unit.\n"
)


class TunedError(KeyError):
    """A study or a value missing from tuned.toml (the message names which and how to write it)."""


@functools.cache
def _table() -> dict[str, dict[str, Any]]:
    with TUNED_PATH.open("rb") as handle:
        return tomllib.load(handle)


def tuned(study: str) -> dict[str, Any]:
    """The chosen values (and their provenance) of one study."""
    table = _table()
    if study not in table:
        raise TunedError(f"{TUNED_PATH}: no [{study}] table; run `fusegraph tune {study} --write`")
    return dict(table[study])


def tuned_studies() -> frozenset[str]:
    """The studies ``tuned.toml`` holds."""
    return frozenset(_table())


SYSTEM_STUDIES: dict[str, tuple[str, ...]] = {
    "head": ("head_ekf", "head_ekf_method1", "head_ekf_kalman", "head_no_gyro"),
    "attitude9": ("broad_ekf", "broad_mag", "broad_mag_batch", "broad_motion", "broad_motion_batch", "broad_bias", "broad_bias_batch",
                  "broad_online", "broad_hard_iron", "broad_hard_iron_batch", "broad_field", "broad_field_batch", "broad_rest", "broad_rest_batch"),
    "gaze": ("gaze_ekf", "gaze_fixation", "gaze_fixation_batch", "gaze_points", "gaze_points_batch", "gaze_head_mag"),
    "bicycle": ("bicycle_ekf", "bicycle_no_removal"),
    "walking": ("walking_fixes",),
    "ultrasonic": ("stonesoup_gnn", "stonesoup_jpda", "uwb_calibrated"),
}
"""The studies whose chosen values each system's methods (its baselines and its graphs) run with."""
CHECK_STUDIES: dict[str, tuple[str, ...]] = {"attitude9": ("broad_nested", "broad_nested_batch")}
"""Tables that hold no choice but a check of the system's choices (``tune broad_nested``: every study re-chosen per held-out
trial), which its bench prints beside its in-sample figures."""


def settings_of(system: str) -> dict[str, dict[str, Any]]:
    """Every study a system's methods read, as written in ``tuned.toml`` (values and provenance); {} for a system without."""
    return {study: tuned(study) for study in SYSTEM_STUDIES.get(system, ())}


def value(study: str, name: str) -> Any:
    """One chosen value of a study."""
    chosen = tuned(study)
    if name not in chosen:
        raise TunedError(f"{TUNED_PATH}: [{study}] has no '{name}'; run `fusegraph tune {study} --write`")
    return chosen[name]


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def write_tuned(study: str, entries: Mapping[str, Any], path: Path = TUNED_PATH) -> Path:
    """Replace one study's table (other studies are kept) and rewrite the file in a stable order."""
    table = {} if not path.is_file() else tomllib.loads(path.read_text())
    table[study] = dict(entries)
    lines = [HEADER]
    for name in sorted(table):
        lines.append(f"[{name}]")
        lines += [f"{key} = {_toml_value(v)}" for key, v in table[name].items()]
        lines.append("")
    path.write_text("\n".join(lines))
    _table.cache_clear()
    return path
