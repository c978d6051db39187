"""`navtopo-bench scenario list|show|validate|render`: the bundled scenarios and scenario files."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from runners.commands.checks import IMAGE_SUFFIXES, open_scenario, writable_file
from runners.commands.console import console, err, note
from runners.commands.errors import Refused

scenario_app = typer.Typer(help="List, inspect, validate and draw scenarios.", no_args_is_help=True)


@scenario_app.command("list")
def scenario_list() -> None:
    """The bundled scenarios, one line each."""
    from scenarios import bundled_names
    from scenarios.scenario import resolve_path
    from scenarios.schema import read_spec

    table = Table(show_header=True)
    table.add_column("name")
    table.add_column("description")
    for name in bundled_names():
        spec = read_spec(resolve_path(name))
        table.add_row(name, spec.description)
    console.print(table)


@scenario_app.command("show")
def scenario_show(
    scenario: Annotated[str, typer.Argument(help="bundled name or YAML file")],
    as_json: Annotated[bool, typer.Option("--json", help="print JSON")] = False,
) -> None:
    """Statistics of a scenario: corridor length, free area, route, trials, bounds."""
    summary = open_scenario(scenario).summary()
    if as_json:
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
        return
    table = Table(show_header=False)
    for key, value in summary.items():
        table.add_row(key, map_import_text(value) if key == "map_import" else str(value))
    console.print(table)


def map_import_text(report: dict) -> str:
    """What a map world's import changed (``Scenario.summary()["map_import"]``), in a few lines."""
    rules = report["rules"]
    if not (rules["small_obstacles"] != "keep" or rules["close_gaps"] or rules["fans"]):
        return f"the raw map (clean: false): {report['free_px']} free pixels"
    seen = f"{rules['resolvable_m'] * 100:.1f} cm, what 2 lidar rays hit at {rules['resolve_range_m']:g} m"
    small = {
        "remove": f"removed {report['removed_px']} px",
        "grow": f"grown by {report['grown_px']} px",
        "keep": "kept",
    }[rules["small_obstacles"]]
    lines = [
        f"small obstacles: {report['islands']} islands under {seen}: {small}",
        f"wall gaps: {report['closed_px']} px closed (slits up to {rules['gap_px']} px)"
        if rules["close_gaps"]
        else "wall gaps: kept",
        f"laser fans: {report['fan_px']} px made wall (no robot of radius {rules['robot_radius_m']:g} m fits, reaching unknown)"
        if rules["fans"]
        else "laser fans: kept",
        f"detached: {report['detached_px']} px; free {report['free_px']} px, {report['changed_px']} px differ from the raw map",
    ]
    return "\n".join(lines)


@scenario_app.command("validate")
def scenario_validate(files: Annotated[list[str], typer.Argument(help="scenario YAML files")]) -> None:
    """Check scenario files; exit 0, or 2 with one line per bad file."""
    from scenarios import ScenarioError, load_scenario

    bad = 0
    for name in files:
        try:
            scenario = load_scenario(name)
        except ScenarioError as exc:
            bad += 1
            err.print(str(exc), highlight=False, soft_wrap=True)
        except Exception as exc:  # noqa: BLE001 - one line per file, and the next file is checked
            bad += 1
            err.print(
                f"{name}: cannot be loaded: {type(exc).__name__}: {exc}".replace("\n", " "), highlight=False, soft_wrap=True
            )
        else:
            for line in scenario.notes:
                note(line)
            console.print(f"{name}: ok", highlight=False)
    if bad:
        raise typer.Exit(2)


@scenario_app.command("render")
def scenario_render(
    scenario: Annotated[str, typer.Argument(help="bundled name or YAML file")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write")],
    no_route: Annotated[bool, typer.Option("--no-route", help="leave out the mapping route")] = False,
) -> None:
    """Draw the ground-truth map, obstacles, mapping route and trials."""
    writable_file(output, "-o", IMAGE_SUFFIXES)
    from scenarios.render import render

    loaded = open_scenario(scenario)
    try:
        path = render(loaded, output, show_route=not no_route)
    except OSError as exc:
        raise Refused(f"-o {output}: cannot be written: {exc.strerror or exc}") from None
    console.print(f"wrote {path}")
