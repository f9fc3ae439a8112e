"""mkdocs hooks: pages that are generated from the code, so they cannot go stale.

* ``<!-- cli -->``: every command's ``--help``, from ``fusegraph.cli.build_parser``;
* ``<!-- datasets -->``: the public datasets the importers read (``fusegraph.datasets.catalogue.DATASETS``);
* ``<!-- settings PREFIX -->``: the settings chosen by ``fusegraph tune`` whose study starts with PREFIX (``tuned.toml``),
  with what they were chosen on and the figures the study printed;
* ``<!-- frames SYSTEM -->``: the system's axes convention (its preset) and a figure of its frames, drawn at build time.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parent


def _cli() -> str:
    import argparse

    from fusegraph.cli import build_parser

    parser = build_parser()
    out = ["```text", parser.format_help().rstrip(), "```"]
    for action in parser._actions:  # noqa: SLF001 - argparse keeps its sub-parsers only here
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                out += [f"\n## `fusegraph {name}`\n", "```text", sub.format_help().rstrip(), "```"]
    return "\n".join(out)


def _datasets() -> str:
    from fusegraph.datasets.catalogue import DATASETS

    out = []
    for d in DATASETS:
        out += [f"## `{d.name}`: {d.title}\n", f"- **Source:** {d.source}", f"- **Licence:** {d.licence}", f"- **Cite:** {d.citation}",
                f"- **Sessions of:** `{d.system}`", f"- **Folder:** {d.notes}", "", "| file | what it holds | needed |", "|---|---|---|"]
        out += [f"| `{p.pattern}` | {p.meaning} | {'yes' if p.required else 'no'} |" for p in d.layout]
        out += ["", "```bash", d.example, "```", ""]
    return "\n".join(out)


def _settings(prefix: str) -> str:
    import fusegraph

    table = tomllib.loads((Path(fusegraph.__file__).parent / "tuned.toml").read_text())
    rows = ["| study | chosen | chosen on | in-sample | cross-validated within the study | unit |", "|---|---|---|---|---|---|"]
    meta = {"seeds", "trials", "runs", "score", "in_sample", "cross_validated", "unit", "total_in_sample", "total_cross_validated"}
    nested = []
    for name, entry in table.items():
        if not name.startswith(prefix):
            continue
        if name.startswith("broad_nested"):  # not a choice: the end-to-end check of the others, said under the table
            solver = "batch" if name.endswith("_batch") else "online"
            nested.append(f"- **{solver}, end to end** (`fusegraph tune broad_nested{' --solver batch' if solver == 'batch' else ''}`): every "
                          f"study re-chosen without the held-out trial, mean total RMSE **{entry['cross_validated']} deg cross-validated** "
                          f"({entry['cross_validated_peer_ratio']}x its peer; inclination {entry['cross_validated_inclination']} deg, "
                          f"{entry['cross_validated_inclination_peer_ratio']}x), against {entry['in_sample_on_main']} deg in-sample with "
                          f"the settings above and {entry['in_sample']} deg for the same procedure on all {len(entry['trials'])} trials.")
            continue
        chosen = ", ".join(f"`{k} = {v}`" for k, v in entry.items() if k not in meta)
        if "seeds" in entry:
            on = f"simulated tuning seeds {entry['seeds'][0]}-{entry['seeds'][-1]}"
        elif "trials" in entry:
            on = f"{len(entry['trials'])} BROAD trials"
        elif "runs" in entry:
            on = ", ".join(entry["runs"])
        else:
            on = "-"
        in_sample = entry.get("in_sample", entry.get("score", "-"))
        rows.append(f"| `{name}` | {chosen} | {on} | {in_sample} | {entry.get('cross_validated', '-')} | {entry.get('unit', '')} |")
    if len(rows) == 2:
        return "_No setting of this system is chosen on data: its defaults are the papers' or the data sheets', cited in the code._"
    return "\n".join(rows + ([""] + nested if nested else []))


def _frames(system: str, prefix: str) -> str:
    from fusegraph.systems.presets import PRESETS

    preset = PRESETS[system]
    return (f"![The frames of the {system} system]({prefix}figures/frames_{system}.png)\n\n**Axes and signs the streams need:** {preset.axes}\n\n"
            f"**Truth:** {preset.truth}")


FRAMES: dict[str, list[tuple[str, tuple[float, float, float], Any]]] = {
    "head": [("world (ENU)", (0, 0, 0), None), ("head: x forward, y left, z up", (1.5, 0.5, 0.3), (0.0, 0.0, 0.6))],
    "attitude9": [("earth (ENU)", (0, 0, 0), None), ("sensor (gyro = accel = mag axes)", (1.5, 0.5, 0.3), (0.4, 0.3, 0.8))],
    "gaze": [("world (ENU); wall at x = wall_m", (0, 0, 0), None), ("head = scene camera: x optical axis, y left, z up", (1.2, 0.5, 0.3), (0.0, 0.0, 0.3))],
    "bicycle": [("world (ENU)", (0, 0, 0), None), ("frame IMU", (1.3, -0.5, 0.2), (0.0, 0.15, 0.0)), ("thigh IMU", (1.4, 0.7, 0.6), (0.0, -0.7, 0.0))],
    "walking": [("building (ENU, z up from the ground floor)", (0, 0, 0), None), ("waist sensor (found from gravity)", (1.5, 0.6, 0.4), (0.0, 0.0, 1.2))],
    "ultrasonic": [("room (z up; receivers on the ceiling)", (0, 0, 0), None), ("tag body (planar: x, y, yaw)", (1.3, 0.6, 0.0), (0.0, 0.0, 0.5))],
}


def _draw_frames(system: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from scipy.spatial.transform import Rotation

    fig = plt.figure(figsize=(5.2, 4.0))
    ax = fig.add_subplot(projection="3d")
    for label, origin, rotvec in FRAMES[system]:
        axes = np.eye(3) * (0.8 if rotvec is None else 0.5)
        if rotvec is not None:
            axes = Rotation.from_rotvec(rotvec).apply(axes)
        for vector, colour, name in zip(axes, ("tab:red", "tab:green", "tab:blue"), "xyz", strict=True):
            ax.quiver(*origin, *vector, color=colour, arrow_length_ratio=0.15, linewidth=2)
            ax.text(*(np.asarray(origin) + 1.12 * vector), name, color=colour)
        ax.text(*(np.asarray(origin) + np.array([0.0, 0.0, -0.25])), label, fontsize=8)
    if system == "ultrasonic":
        grid = np.array([(x, y, 1.2) for x in (-0.3, 0.0, 0.3) for y in (0.0, 0.3, 0.6)])
        ax.scatter(*grid.T, marker="s", color="grey", label="receivers")
    ax.set(xlim=(-0.5, 2.2), ylim=(-0.8, 1.4), zlim=(-0.4, 1.4), xticks=[], yticks=[], zticks=[])
    ax.view_init(elev=22, azim=-60)
    ax.set_title(f"{system}: frames", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def on_pre_build(config: Any) -> None:
    for system in FRAMES:
        _draw_frames(system, DOCS / "figures" / f"frames_{system}.png")


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    markdown = markdown.replace("<!-- cli -->", _cli()) if "<!-- cli -->" in markdown else markdown
    markdown = markdown.replace("<!-- datasets -->", _datasets()) if "<!-- datasets -->" in markdown else markdown
    markdown = re.sub(r"<!-- settings (\w+) -->", lambda m: _settings(m.group(1)), markdown)
    prefix = "../" * page.file.src_uri.count("/")
    return re.sub(r"<!-- frames (\w+) -->", lambda m: _frames(m.group(1), prefix), markdown)
