"""``report.html``: one self-contained page (no network, no script): the table, the plots as
embedded PNG data URIs, each run's manifest and the command that reproduces it.

A Content-Security-Policy forbids every load but inline styles and ``data:`` images, so a page
that tried to fetch anything would show it as a console error (tests/test_report_html.py).
"""

from __future__ import annotations

import base64
import html
import json
import re
from typing import TYPE_CHECKING, Any

import yaml

from reports.contents import Report, RunSection
from reports.failures import failure_rows
from reports.failures import rows_html as failure_rows_html
from reports.tables import HEADERS, NOTES, cells, paper_comparison, table_rows
from reports.trial_table import GAP_NOTE, gap_notes
from reports.trial_table import table_html as trial_table_html

if TYPE_CHECKING:
    from reports.plots import PlotResult
    from reports.records import Manifest

CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.5rem auto; max-width: 1400px;
       padding: 0 1rem; color: #1a1a1a; line-height: 1.4; }
h1 { font-size: 1.5rem; } h2 { font-size: 1.2rem; margin-top: 2rem; border-bottom: 1px solid #ccc; }
h3 { font-size: 1rem; }
table.results { border-collapse: collapse; font-size: 0.8rem; margin: 0.5rem 0 1rem; }
table.results th, table.results td { border: 1px solid #ccc; padding: 0.25rem 0.4rem; text-align: right;
       vertical-align: top; }
table.results th { background: #f0f0f0; } table.results td:nth-child(-n+3) { text-align: left; }
table.results tr.paper td { font-style: italic; color: #555; background: #fafafa; }
table.results tr.narrow td { background: #fff4e0; }
dl.manifest { display: grid; grid-template-columns: max-content 1fr; gap: 0.15rem 1rem; font-size: 0.85rem; }
dl.manifest dt { font-weight: 600; } dl.manifest dd { margin: 0; }
pre { background: #f6f6f6; padding: 0.5rem; overflow-x: auto; font-size: 0.8rem; }
figure { margin: 1rem 0; } figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 0.85rem; color: #444; } .note { color: #8a4b00; font-size: 0.85rem; }
"""


# the bytes of a file name that are not UTF-8, as Python holds them in a str (PEP 383: U+DC80-U+DCFF)
UNDECODED = re.compile("[\udc80-\udcff]")


def shown(text: str) -> str:
    """``text`` with each byte of a file name that is not UTF-8 written ``\\xNN``: a page or a
    table is UTF-8, which cannot hold the byte itself (a folder named in Latin-1, say)."""
    return UNDECODED.sub(lambda m: f"\\x{ord(m[0]) - 0xDC00:02x}", text)


def _e(value: Any) -> str:
    return html.escape(shown(str(value)), quote=True)


def _inline(text: str) -> str:
    """Escape, then the two Markdown marks the table notes use: **bold** and *italic*."""
    text = _e(text)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"\*(.+?)\*", r"<em>\1</em>", text)


def table_html(report: Report) -> str:
    rows = table_rows([s.run for s in report.sections])
    runs = [s.run for s in report.sections]
    head = "".join(f"<th>{_e(title)}</th>" for title in HEADERS.values())
    body = []
    for row in rows:
        c = cells(row)
        tds = "".join(f"<td>{_e(c[key].strip('*'))}</td>" for key in HEADERS)
        body.append(f'<tr class="{"paper" if row.paper else "measured"}">{tds}</tr>')
    notes = "".join(f"<li>{_inline(n)}</li>" for n in NOTES + paper_comparison(rows, runs) + gap_notes(runs))
    return (
        f'<table class="results" id="table1"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table><ul>{notes}</ul>'
    )


def figure_html(plot: PlotResult, base: str) -> str:
    if plot.png is None:
        return f'<p class="note">{_e(plot.title)}: not drawn: {_e(plot.note)}</p>'
    data = base64.b64encode(plot.png.read_bytes()).decode("ascii")
    svg = next((f for f in plot.files if f.suffix == ".svg"), None)
    caption = _e(plot.caption) + (f" (vector: <code>{_e(base + svg.name)}</code>)" if svg else "")
    note = f'<p class="note">{_e(plot.note)}</p>' if plot.note else ""
    return (
        f'<figure id="{_e(plot.name)}"><img src="data:image/png;base64,{data}" alt="{_e(plot.title)}">'
        f"<figcaption><strong>{_e(plot.title)}</strong>: {caption}</figcaption>{note}</figure>"
    )


def _json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, ensure_ascii=False)


SETTINGS = {
    "precise": "exact wheel odometry, no lidar range noise",
    "noisy": "wheel odometry with 2 % of the distance and 0.5°/m of drift, lidar range noise 1 cm",
}


def setting_meaning(m: Manifest) -> str:
    """What the run's setting is, in words: a named one, or the scenario file's own noise ("custom")."""
    name = (m.setting or "").split(",")[0]
    if name in SETTINGS:
        return SETTINGS[name]
    return f"the scenario file's own: odometry noise {_json(m.odometry_noise)}, lidar range noise {m.range_noise or 0:g} m"


def odometry_sources(config: dict[str, Any]) -> str:
    """Per system, the odometry its config says it uses (``odometry.source``: wheel, or lidar
    odometry seeded by the wheels); NavTopo tracks on the wheels' and keeps lidar odometry's for
    map-frame hints (``lidar_hints``)."""
    parts = []
    for system, cfg in config.items():
        if not isinstance(cfg, dict):
            continue
        odometry = cfg.get("odometry") if isinstance(cfg.get("odometry"), dict) else None
        if odometry is not None and odometry.get("source"):
            seeded = " seeded by the wheels" if odometry.get("source") == "lidar" and odometry.get("seed_with_wheel") else ""
            parts.append(f"{system}: {odometry['source']}{seeded}")
        elif "lidar_hints" in cfg:
            hints = " (lidar odometry for map-frame hints)" if cfg.get("lidar_hints") else ""
            parts.append(f"{system}: wheel{hints}")
        elif system == "oracle":
            parts.append(f"{system}: the true pose (the reference)")
        else:
            parts.append(f"{system}: the simulator's odometry")
    return "; ".join(parts)


def manifest_html(section: RunSection) -> str:
    m = section.run.manifest
    s = m.scenario
    scenario = s.name + (f" — {s.description}" if s.description else "")
    facts = [
        ("scenario", scenario),
        ("scenario file", s.file or "–"),
        ("scenario sha256", m.scenario_sha256 or "–"),
        (
            "scenario stats",
            ", ".join(
                f"{label} {value}"
                for label, value in (
                    ("corridors (m)", s.corridor_length_m),
                    ("free area (m²)", s.free_area_m2),
                    ("route (m)", s.route_length_m),
                    ("trials", s.trial_count),
                    ("trial distance mean (m)", s.trial_distance_mean_m),
                )
                if value is not None
            )
            or "–",
        ),
        ("systems", ", ".join(m.systems)),
        ("seed", m.seed),
        ("trials run", "–" if m.trial_count is None else m.trial_count),
        ("setting", f"{section.run.setting}: {setting_meaning(m)}"),
        ("odometry each system uses", odometry_sources(m.config) or "–"),
        ("odometry noise", _json(m.odometry_noise)),
        ("range noise (m)", "–" if m.range_noise is None else m.range_noise),
        ("protocol", _json(m.protocol.model_dump())),
        ("maps from", m.maps_from or "– (mapped in this run)"),
        ("git revision", m.git_revision or "–"),
        ("created", m.created or "–"),
        ("versions", ", ".join(f"{k} {v}" for k, v in m.versions.items()) or "–"),
        ("machine", _json(m.machine)),
        ("files missing", ", ".join(section.run.missing) or "none"),
        ("records repeated", ", ".join(f"{s} trial {t}" for s, t in dict.fromkeys(section.run.repeated)) or "none"),
    ]
    items = "".join(f"<dt>{_e(k)}</dt><dd>{_e(v)}</dd>" for k, v in facts)
    config = yaml.safe_dump(m.config, sort_keys=False)
    return (
        f'<dl class="manifest">{items}</dl>'
        f"<h3>Reproduce</h3><p>With <code>{_e(section.config_file)}</code> (the run's resolved configs, beside this page):</p>"
        f'<pre class="command"><code>{_e(section.command)}</code></pre>'
        f"<details><summary>configs ({_e(section.config_file)})</summary><pre>{_e(config)}</pre></details>"
    )


def page(report: Report) -> str:
    several = len(report.sections) > 1
    title = "navtopo-bench report: " + ", ".join(dict.fromkeys(s.run.label for s in report.sections))
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f'<meta http-equiv="Content-Security-Policy" content="{CSP}">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{_e(title)}</h1>",
    ]
    if report.study:
        parts.append(f"<h2>{_e(report.study_title or 'Study')}</h2>")
        parts += [figure_html(p, "plots/") for p in report.study]
    parts += [
        "<h2>Table 1: memory, planning time and efficiency</h2>",
        table_html(report),
        "<p>Also as <code>table.md</code>, <code>table.csv</code> and <code>table.tex</code> beside this page.</p>",
    ]
    if report.combined:
        parts.append("<h2>All runs</h2>")
        parts += [figure_html(p, "plots/") for p in report.combined]
    for section in report.sections:
        base = f"plots/{section.key}/" if several else "plots/"
        parts.append(f"<h2>{_e(section.run.label)}</h2>")
        parts += [figure_html(p, base) for p in section.plots]
        parts.append("<h3>Trials</h3>")
        parts.append(trial_table_html(section.run))
        parts.append(f'<p class="note">{_inline(GAP_NOTE)}</p>')
        parts.append("<h3>Failed trials</h3>")
        parts.append(failure_rows_html(failure_rows(section.run)))
        parts += [figure_html(p, base + "failures/") for p in section.failures]
        parts.append("<h3>Manifest</h3>")
        parts.append(manifest_html(section))
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_html(report: Report) -> None:
    report.html.write_text(page(report), encoding="utf-8")
