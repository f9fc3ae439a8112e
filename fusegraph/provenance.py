"""Which recordings the settings on main were chosen on, so that a report over sessions can say which of its figures are
in-sample: a session that is one of those recordings is scored by settings that saw it.

The recordings come from where each choice is written: ``tuned.toml`` (``trials`` of the BROAD studies, ``runs`` of the
UWB study), the activity model's own provenance (``models/activity_waist.json``), and the walking front end's choices
that live in code (``GAIT_PARTICIPANTS``, ``PHONE_RECORDINGS``). A session is matched by its ``[session] dataset`` and
``trial`` (or ``subject``), which every importer writes, a simulated session by its ``seed``.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .tuned import SYSTEM_STUDIES, TunedError, tuned

GAIT_PARTICIPANTS = ("HA/001", "HA/002")
"""The Mobilise-D participants the walking front end's step thresholds (``frontends.pdr.PdrConfig``, which every walking
solver runs with) were chosen on in-sample (``bench gait`` re-chooses them without each participant); ``--solver gait``'s
step length is Mobilise-D's published setting (``frontends.gait.CITED``), chosen on none."""
PHONE_RECORDINGS = ("Pixel_Jamie_Hard_BackPocket_1", "Pixel_Jamie_Hard_FrontPocket_1", "Pixel_Jamie_Hard_NeckPouch_1",
                    "Samsung_Carmelo_Hard_FrontPocket_1", "Samsung_Dario_Hard_BackPocket_1")
"""The Oxford recordings ``--solver steps``'s peak threshold (``frontends.pdr.PHONE``) was chosen on (``bench walking``
re-chooses it without each recording)."""
ACTIVITY_MODEL = Path(__file__).parent / "models" / "activity_waist.json"
"""The waist activity model, whose ``provenance`` names the HAPT recordings it was fitted on."""


@dataclass(frozen=True)
class ChosenOn:
    """One choice of settings and the recordings it was made on."""

    what: str
    """The choice, e.g. ``tuned.toml [broad_mag]``."""
    dataset: str
    """The start of the ``[session] dataset`` of its recordings (``BROAD`` also matches BROAD's head and gaze sessions;
    empty for simulated seeds, which ``fusegraph simulate`` writes as ``[session] seed``)."""
    key: str
    """What names a recording: ``trial`` or ``subject`` of the ``[session]`` table."""
    names: frozenset[str]
    """The recordings' trials (or subjects)."""


@functools.cache
def chosen_on(system: str) -> tuple[ChosenOn, ...]:
    """Every choice the system's methods run with and the recordings (or simulated seeds) it was made on (made once per
    process: a report asks it for every session)."""
    out: list[ChosenOn] = []
    studies = SYSTEM_STUDIES.get(system, ())
    if system == "gaze":  # its head is the 9-axis estimate's graph with that system's settings (systems.gaze)
        studies = (*studies, *SYSTEM_STUDIES["attitude9"])
    for study in studies:
        try:
            entry = tuned(study)
        except TunedError:
            continue
        if "trials" in entry:
            out.append(ChosenOn(f"tuned.toml [{study}]", "BROAD", "trial", frozenset(map(str, entry["trials"]))))
        if "runs" in entry:
            out.append(ChosenOn(f"tuned.toml [{study}]", "UWB", "trial", frozenset(map(str, entry["runs"]))))
        if "seeds" in entry:  # the first and last tuning seed of a simulated study
            first, last = (int(x) for x in entry["seeds"])
            out.append(ChosenOn(f"tuned.toml [{study}]", "", "seed", frozenset(str(x) for x in range(first, last + 1))))
    if system == "walking":
        out += [ChosenOn("the activity model (models/activity_waist.json)", "UCI HAPT", "trial", _activity_recordings()),
                ChosenOn("the step thresholds (frontends.pdr)", "Mobilise-D", "subject",
                         frozenset(GAIT_PARTICIPANTS)),
                ChosenOn("--solver steps's peak threshold (frontends.pdr.PHONE)", "Oxford", "trial", frozenset(PHONE_RECORDINGS))]
    return tuple(out)


def _activity_recordings() -> frozenset[str]:
    """The HAPT recordings the activity model was fitted on (read once, through ``chosen_on``'s cache: the model is ~0.5 MB)."""
    return frozenset(json.loads(ACTIVITY_MODEL.read_text()).get("provenance", {}).get("recordings", []))


def choices_that_saw(system: str, header: Mapping[str, Any]) -> list[str]:
    """The choices of ``chosen_on(system)`` made on the recording whose ``[session]`` table is ``header``."""
    dataset = str(header.get("dataset", ""))
    return [c.what for c in chosen_on(system) if dataset.startswith(c.dataset) and str(header.get(c.key, "")) in c.names]
