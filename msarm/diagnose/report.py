"""The report of a gap diagnosis: plots, Markdown, a self-contained HTML page, JSON.

:func:`write_report` writes, into one folder and file by file atomically:

- ``diagnosis.json``: :meth:`~msarm.diagnose.select.Diagnosis.as_dict`, with the "where"
  breakdowns given in its ``where`` section (see
  :meth:`~msarm.diagnose.result.Diagnosis.with_where`);
- ``waterfall.png`` (:func:`plot_waterfall`): per channel group, the pooled held-out RMSE of
  the residual for the nominal model and after each selected effect, each step's drop shaded;
- ``gap.png`` (:func:`plot_gap`): per group, the held-out RMSE of each channel before and after
  the selected effects;
- ``where-<kind>.png``: one heat map (:func:`msarm.diagnose.where.plot_heatmap`) per "where"
  breakdown given (``joint_torque``, ``drive``, ``cable_length``, ...);
- ``report.md``: a title and summary, what the answer was made from (model and its SHA-256,
  code fingerprint, logs, residual settings), the terms it uses, the "Where" section (each
  breakdown's tables, its heat map linked, and why a residual was not broken down), then the
  diagnosis' own sections (which effects, how far the gap shrinks, the candidates tried)
  with the waterfall and gap plots linked (relative paths);
- ``report.html``: the same content as one self-contained page (the PNGs embedded as base64
  ``data:`` images) that can be mailed or archived alone. Markdown is rendered with
  ``markdown-it-py`` (a dependency of ``rich``), raw HTML in the text is escaped.
"""

from __future__ import annotations

import base64
import html
import os
import re
import tempfile
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from msarm.diagnose.builder import GROUP_UNITS
from msarm.diagnose.result import Diagnosis, SelectedEffect
from msarm.diagnose.where import GapBreakdown, plot_heatmap
from msarm.errors import InputError
from msarm.interrupts import signals_held
from msarm.io.atomic import STALE_TEMP_AGE_S, write_bytes_atomic, write_json_atomic

__all__ = ["REPORT_FILES", "plot_gap", "plot_waterfall", "render_html", "write_report"]

#: The fixed files of a report, by the key :func:`write_report` returns them under.
REPORT_FILES = {
    "json": "diagnosis.json",
    "waterfall": "waterfall.png",
    "gap": "gap.png",
    "markdown": "report.md",
    "html": "report.html",
}

_KIND = re.compile(r"^[A-Za-z0-9_.-]+$")
_COLOURS = {"nominal": "0.55", "kept": "tab:blue", "drop": "tab:green", "rise": "tab:red"}
#: Colour of a waterfall bar after an effect that acts on other groups only.
_OTHER_GROUPS = "0.8"
#: Width the waterfall's legend adds to the figure [in].
_LEGEND_WIDTH = 3.0


def _check_diagnosis(diagnosis: Diagnosis) -> None:
    if not isinstance(diagnosis, Diagnosis):
        raise InputError(f"diagnosis: expected a Diagnosis, got {type(diagnosis).__name__}")
    if not diagnosis.groups:
        raise InputError("diagnosis: it has no channel group to report on")


def _step_labels(diagnosis: Diagnosis) -> list[str]:
    """``["nominal model", "+ effect1", ...]``, one per waterfall step."""
    labels = ["nominal model", *(f"+ {s.name}" for s in diagnosis.selected)]
    if len(labels) != len(diagnosis.waterfall):  # defensive: label by index
        labels = ["nominal model", *(f"step {k}" for k in range(1, len(diagnosis.waterfall)))]
    return labels


def _short(value: float) -> str:
    """A bar's value in at most about eight characters (``0.000165`` as ``1.65e-04``)."""
    return f"{value:.3g}" if value == 0 or 1e-2 <= abs(value) < 1e4 else f"{value:.2e}"


def plot_waterfall(diagnosis: Diagnosis, path: str | Path) -> Path:
    """Pooled held-out RMSE of each group after each selection step, as a waterfall.

    One panel per group of ``diagnosis.groups``. Bar ``k`` is the group's pooled held-out RMSE
    [its unit, :data:`~msarm.diagnose.builder.GROUP_UNITS`] after the first ``k`` terms of the
    final model (fitted together, added in selection order; bar 0: the nominal model), which
    need not match the gains at selection time (each term's fit at its step, an explained
    energy share; a note under the panels says so); the drop from the previous step is
    shaded (green, red for a rise) and labelled with the RMSE and the drop's size in % of the
    nominal RMSE (a grey bar, an effect on other groups that leaves this one unchanged, is not
    labelled). The panel title gives the group's total shrink ``1 - RMSE_after /
    RMSE_nominal``. With nothing selected, each panel has the nominal bar only. A legend
    (:func:`_waterfall_legend`) names the colours that the figure uses.

    Args:
        diagnosis: The diagnosis.
        path: PNG file to write (atomically).

    Returns:
        The path written.

    Raises:
        InputError: ``diagnosis`` is not a :class:`Diagnosis` or has no group.
    """
    from msarm.plots import plt, save_figure

    _check_diagnosis(diagnosis)
    labels = _step_labels(diagnosis)
    groups = diagnosis.groups
    width = max(4.2, 1.0 + 0.9 * len(labels))
    fig, axes = plt.subplots(
        1,
        len(groups),
        figsize=(width * len(groups) + _LEGEND_WIDTH, 4.6),
        squeeze=False,
        layout="constrained",
    )
    x = np.arange(len(labels))
    used: set[str] = {"nominal"}  # the legend's entries: the colours drawn
    for ax, g in zip(axes[0], groups, strict=True):
        unit = GROUP_UNITS[g]
        values = np.array([step[g] for step in diagnosis.waterfall], dtype=float)
        nominal = values[0]
        acts = [True] + [g in s.groups for s in diagnosis.selected]
        acts += [True] * (len(values) - len(acts))
        colours = [_COLOURS["nominal"]] + [
            _COLOURS["kept"] if a else _OTHER_GROUPS for a in acts[1 : len(values)]
        ]
        ax.bar(x, values, color=colours, width=0.6, zorder=2)
        used.update("kept" if a else "other" for a in acts[1 : len(values)])
        for k in range(1, len(values)):
            drop = values[k - 1] - values[k]
            if drop != 0:
                used.add("drop" if drop > 0 else "rise")
            ax.bar(
                x[k],
                abs(drop),
                bottom=min(values[k], values[k - 1]),
                width=0.6,
                color=_COLOURS["drop" if drop >= 0 else "rise"],
                alpha=0.3,
                hatch="//",
                edgecolor=_COLOURS["drop" if drop >= 0 else "rise"],
                zorder=2,
            )
            ax.plot([x[k - 1] + 0.3, x[k] - 0.3], [values[k - 1]] * 2, color="0.4", lw=0.8)
            share = 100.0 * drop / nominal if nominal > 0 else 0.0
            if not acts[k] and abs(share) < 0.05:
                continue  # an effect on other groups: the bar says it all, no label to crowd
            change = f"{-share:+.1f} %" if abs(share) >= 0.05 else "0.0 %"
            ax.annotate(
                f"{_short(values[k])}\n{change}",
                (x[k], max(values[k], values[k - 1])),
                xytext=(0, 3),
                textcoords="offset points",
                ha="center",
                va="bottom",
                fontsize=8,
            )
        ax.annotate(
            _short(nominal),
            (x[0], nominal),
            xytext=(0, 3),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize=8,
        )
        if len(values) > 1:
            ax.axhline(values[-1], color="k", lw=0.8, ls="--", zorder=1)
            used.add("final")
        ax.set_xticks(x, labels, rotation=25, ha="right")
        ax.set_ylabel(f"pooled held-out RMSE [{unit}]")
        ax.set_ylim(0.0, 1.22 * max(float(values.max()), 1e-300))  # room for two-line labels
        shrink = 1.0 - values[-1] / nominal if nominal > 0 else 0.0
        ax.set_title(f"{g}: shrink {100 * shrink:.1f} %")
        ax.set_xlim(-0.6 if len(x) > 1 else -1.5, x[-1] + (0.6 if len(x) > 1 else 1.5))
        ax.grid(axis="y", alpha=0.3, zorder=0)
    fig.legend(
        handles=_waterfall_legend(used), loc="outside right center", fontsize=8, frameon=False
    )
    fig.suptitle(
        "held-out gap after each selected effect:\nthe final model, its terms added in "
        "selection order" + ("" if diagnosis.selected else " (nothing selected)")
    )
    fig.supxlabel(
        "bars: pooled held-out RMSE of the residual; labels: RMSE and the step's change\n"
        "as a share of the nominal model's RMSE (not the gain when selected,\n"
        "an explained-energy share from the fit at that step)",
        fontsize=8,
    )
    return save_figure(fig, path)


def _waterfall_legend(used: set[str]) -> list:
    """Proxy artists for the waterfall's colours, those in ``used`` (in a fixed order)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    def shaded(kind: str, label: str) -> Patch:
        colour = _COLOURS[kind]
        return Patch(facecolor=colour, alpha=0.3, hatch="//", edgecolor=colour, label=label)

    entries = {
        "nominal": Patch(facecolor=_COLOURS["nominal"], label="nominal model"),
        "kept": Patch(facecolor=_COLOURS["kept"], label="after an effect acting on this group"),
        "other": Patch(facecolor=_OTHER_GROUPS, label="after an effect on other groups only"),
        "drop": shaded("drop", "the step's drop"),
        "rise": shaded("rise", "the step's rise"),
        "final": Line2D([], [], color="k", lw=0.8, ls="--", label="final RMSE"),
    }
    return [artist for kind, artist in entries.items() if kind in used]


def plot_gap(diagnosis: Diagnosis, path: str | Path) -> Path:
    """Held-out RMSE per channel before and after the selected effects, one panel per group.

    Grouped bars per channel (joint or cable): the nominal model's held-out RMSE and the RMSE
    left after subtracting the selected effects' prediction [the group's unit], the shrink
    ``1 - after / before`` [%] written above each pair.

    Args:
        diagnosis: The diagnosis.
        path: PNG file to write (atomically).

    Returns:
        The path written.

    Raises:
        InputError: ``diagnosis`` is not a :class:`Diagnosis` or has no group.
    """
    from msarm.plots import plt, save_figure

    _check_diagnosis(diagnosis)
    groups = diagnosis.groups
    widest = max(len(diagnosis.channel_names[g]) for g in groups)
    fig, axes = plt.subplots(
        len(groups),
        1,
        figsize=(max(7.0, 1.2 + 0.95 * widest), 3.4 * len(groups)),
        squeeze=False,
        layout="constrained",
    )
    for ax, g in zip(axes[:, 0], groups, strict=True):
        unit = GROUP_UNITS[g]
        names = diagnosis.channel_names[g]
        before = np.asarray(diagnosis.gap_before[g], dtype=float)
        after = np.asarray(diagnosis.gap_after[g], dtype=float)
        shrink = diagnosis.shrink(g)
        x = np.arange(len(names))
        ax.bar(x - 0.2, before, width=0.4, color=_COLOURS["nominal"], label="nominal model")
        ax.bar(x + 0.2, after, width=0.4, color=_COLOURS["kept"], label="after the effects")
        for k in range(len(names)):
            ax.annotate(
                f"{100 * shrink[k]:.0f} %",
                (x[k], max(before[k], after[k])),
                xytext=(0, 3),
                textcoords="offset points",
                ha="center",
                va="bottom",
                fontsize=7,
            )
        tilted = len(names) > 5
        ax.set_xticks(x, names, rotation=20 if tilted else 0, ha="right" if tilted else "center")
        ax.set_ylabel(f"held-out RMSE [{unit}]")
        top = float(max(before.max(initial=0.0), after.max(initial=0.0)))
        ax.set_ylim(0.0, 1.35 * top if top > 0 else 1.0)
        pooled_before = float(np.sqrt(np.mean(before**2)))
        pooled_after = float(np.sqrt(np.mean(after**2)))
        ax.set_title(
            f"{g}: pooled {pooled_before:.3g} -> {pooled_after:.3g} {unit} "
            f"(shrink {100 * diagnosis.group_shrink(g):.1f} %)"
        )
        ax.legend(fontsize=8, loc="upper right", ncol=2)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle("held-out gap per channel, before and after the selected effects")
    return save_figure(fig, path)


def _demote(markdown: str, levels: int = 1) -> str:
    """Move every ATX heading of ``markdown`` down by ``levels`` (``#`` -> ``##``)."""
    return re.sub(
        r"^(#{1,6})(?= )",
        lambda m: "#" * min(6, len(m.group(1)) + levels),
        markdown,
        flags=re.MULTILINE,
    )


def _effect_summary(effect: SelectedEffect, limit: int = 4) -> str:
    parts = effect.parameter_texts(limit)
    confidence = f", confidence {effect.confidence:.2f}" if np.isfinite(effect.confidence) else ""
    return f"**{effect.name}** ({', '.join(parts)}{confidence})"


def _markdown(
    diagnosis: Diagnosis, where: Mapping[str, tuple[GapBreakdown, str]], images: Mapping[str, str]
) -> str:
    """The report as Markdown, images linked by their file names."""
    lines = ["# Sim-to-real gap report", ""]
    if diagnosis.selected:
        lines.append(
            "Named effects, in the order they were selected: "
            + "; ".join(_effect_summary(s) for s in diagnosis.selected)
            + "."
        )
    else:
        lines.append(
            "No candidate effect explains the held-out gap better than the nominal model by "
            f"more than {diagnosis.threshold:.3g}: nothing named."
        )
    lines += [
        "",
        "Held-out gap shrink per channel group (final model, RMSE): "
        + ", ".join(
            f"{g} {100 * diagnosis.group_shrink(g):.1f} % "
            f"({diagnosis.waterfall[0][g]:.4g} -> {diagnosis.waterfall[-1][g]:.4g} "
            f"{GROUP_UNITS[g]})"
            for g in diagnosis.groups
        )
        + ".",
        "",
        *diagnosis.settings_markdown(),
        "",
        *diagnosis.glossary_markdown(),
        "",
        "## Where the gap lies (training runs)",
        "",
    ]
    if not where:
        lines += ["No breakdown was computed.", ""]
    for kind, (breakdown, image) in where.items():
        body = _demote(breakdown.to_markdown().strip(), 1)
        head, _, rest = body.partition("\n")
        lines += [head, "", f"![where the {kind} gap lies]({image})", "", rest.strip(), ""]
    skipped = [
        f"- {kind}: {entry['skipped']}"
        for kind, entry in diagnosis.where.items()
        if kind not in where and isinstance(entry, dict) and "skipped" in entry
    ]
    if skipped:
        lines += ["Residuals not broken down:", "", *skipped, ""]
    diagnosis_md = _demote(diagnosis.to_markdown(preamble=False).strip(), 1).splitlines()
    figures = [
        f"![held-out gap after each selected effect]({images['waterfall']})",
        "",
        f"![held-out gap per channel]({images['gap']})",
        "",
    ]
    at = next((k for k, line in enumerate(diagnosis_md) if line.startswith("### How far")), None)
    if at is None:
        diagnosis_md += ["", *figures]
    else:
        diagnosis_md[at + 1 : at + 1] = ["", *figures[:-1]]
    lines += diagnosis_md
    return "\n".join(lines).rstrip() + "\n"


_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; max-width: 1100px;
       margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
h1, h2, h3, h4 { line-height: 1.2; }
h2 { border-bottom: 1px solid #ddd; padding-bottom: 0.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
th { background: #f3f3f3; }
tr:nth-child(even) td { background: #fafafa; }
img { max-width: 100%; height: auto; border: 1px solid #eee; }
code { background: #f3f3f3; padding: 0 0.2em; }
"""


def render_html(markdown: str, images: Mapping[str, bytes], title: str = "") -> str:
    """A self-contained HTML page of ``markdown``, the linked images embedded as base64.

    Args:
        markdown: The Markdown text (CommonMark with GFM tables); raw HTML in it is escaped.
        images: PNG bytes by the file name the Markdown links them by (``![..](name)``).
        title: Page title (default: the first heading).

    Returns:
        The HTML page.
    """
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(markdown)
    for name, data in images.items():
        uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
        body = body.replace(f'src="{html.escape(name, quote=True)}"', f'src="{uri}"')
    if not title:
        heading = re.search(r"^#+ (.+)$", markdown, flags=re.MULTILINE)
        title = heading.group(1) if heading else "report"
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        f"{body}</body>\n</html>\n"
    )


#: The prefix of the hidden folder a report is staged in before its files are moved out.
_STAGING_PREFIX = ".report-"


def _remove_stale_staging(out: Path) -> list[Path]:
    """Remove staging folders a killed writer left in ``out`` (older than a minute).

    A report is written into a hidden ``.report-*`` folder and its files moved out; a
    SIGKILL leaves that folder, which no later report would otherwise remove (a review found
    one holding a partial ``diagnosis.json`` after every rerun). Younger ones may belong to
    a writer still at work (:data:`~msarm.io.atomic.STALE_TEMP_AGE_S`).

    Returns:
        The folders removed.
    """
    import shutil
    import time

    removed = []
    for folder in out.glob(f"{_STAGING_PREFIX}*"):
        try:
            old = time.time() - folder.stat().st_mtime > STALE_TEMP_AGE_S
        except OSError:
            continue
        if folder.is_dir() and old:
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def write_report(
    diagnosis: Diagnosis,
    out_dir: str | Path,
    breakdowns: Mapping[str, GapBreakdown] | None = None,
    extra_files: Mapping[str, bytes] | None = None,
) -> dict[str, Path]:
    """Write the diagnosis report (JSON, plots, Markdown, HTML) into ``out_dir``.

    See the module docstring for the files. The report is written whole into a hidden
    staging folder inside ``out_dir`` first, then its files are moved into place (the JSON
    last, SIGINT and SIGTERM held back until every move is done,
    :func:`msarm.interrupts.signals_held`), so that an interrupted run leaves the previous
    report as it was rather than a mix of two; the folder is created if needed. A previous
    report's files are replaced, and its heat maps of residuals this diagnosis does not have
    are removed (they would be mistaken for this one's).

    Args:
        diagnosis: The diagnosis (:func:`msarm.diagnose.select.diagnose`).
        out_dir: Folder to write into.
        breakdowns: "Where" breakdowns (:func:`msarm.diagnose.where.diagnose_where`) by
            residual kind, in the order they should appear; the kind names the heat map
            ``where-<kind>.png`` (letters, digits, ``_``, ``.``, ``-``).
        extra_files: More files of the same report, by file name (letters, digits, ``_``,
            ``.``, ``-``), with their bytes; returned under their file names.

    Returns:
        The paths written, by name: ``json``, ``waterfall``, ``gap``, ``where-<kind>`` for each
        breakdown, ``markdown`` and ``html`` (see :data:`REPORT_FILES`), and the extra files.

    Raises:
        InputError: ``diagnosis`` is not a :class:`Diagnosis`; ``out_dir`` is a file or
            cannot be created (under a file, no permission; named, with the reason); a
            breakdown that is not a :class:`GapBreakdown` or a kind unfit for a file name.
    """
    _check_diagnosis(diagnosis)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"out_dir: {out} exists and is not a folder")
    where = dict(breakdowns or {})
    for kind, breakdown in where.items():
        if not isinstance(kind, str) or not _KIND.match(kind):
            raise InputError(
                f"breakdowns: kind {kind!r} cannot name a file (letters, digits, _ . - only)"
            )
        if not isinstance(breakdown, GapBreakdown):
            raise InputError(
                f"breakdowns: {kind!r} is a {type(breakdown).__name__}, not a GapBreakdown"
            )
    extras = dict(extra_files or {})
    taken = {*REPORT_FILES.values(), *(f"where-{kind}.png" for kind in where)}
    for name in extras:
        if not isinstance(name, str) or not _KIND.match(name) or name in taken:
            raise InputError(
                f"extra_files: {name!r} cannot name a file of the report (letters, digits, "
                f"_ . - only, and not one of {sorted(taken)})"
            )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(
            f"out_dir: cannot create the folder {out}: {exc.strerror or exc}"
        ) from None
    _remove_stale_staging(out)
    with tempfile.TemporaryDirectory(dir=out, prefix=_STAGING_PREFIX) as staging:
        staged = _write_report_files(diagnosis, Path(staging), where, extras)
        paths: dict[str, Path] = {}
        # all or none: a Ctrl-C or SIGTERM between two moves left a mix of two reports
        with signals_held():
            for key in sorted(staged, key=lambda k: k == "json"):  # the JSON last
                paths[key] = out / staged[key].name
                os.replace(staged[key], paths[key])
            for old in out.glob("where-*.png"):  # a previous report's maps of other residuals
                if old.name not in taken:
                    old.unlink()
    return paths


def _write_report_files(
    diagnosis: Diagnosis,
    out: Path,
    where: Mapping[str, GapBreakdown],
    extras: Mapping[str, bytes],
) -> dict[str, Path]:
    """Every file of the report into ``out`` (see :func:`write_report`)."""
    given = {k: b.as_dict() for k, b in where.items() if k not in diagnosis.where}
    if given:  # the breakdowns in the JSON too
        diagnosis = replace(diagnosis, where={**diagnosis.where, **given})
    paths: dict[str, Path] = {}
    paths["json"] = write_json_atomic(out / REPORT_FILES["json"], diagnosis.as_dict())
    paths["waterfall"] = plot_waterfall(diagnosis, out / REPORT_FILES["waterfall"])
    paths["gap"] = plot_gap(diagnosis, out / REPORT_FILES["gap"])
    linked: dict[str, tuple[GapBreakdown, str]] = {}
    for kind, breakdown in where.items():
        name = f"where-{kind}"
        paths[name] = plot_heatmap(breakdown, out / f"{name}.png")
        linked[kind] = (breakdown, paths[name].name)
    images = {"waterfall": paths["waterfall"].name, "gap": paths["gap"].name}
    markdown = _markdown(diagnosis, linked, images)
    paths["markdown"] = write_bytes_atomic(out / REPORT_FILES["markdown"], markdown.encode())
    embedded = {p.name: p.read_bytes() for p in paths.values() if p.suffix == ".png"}
    page = render_html(markdown, embedded, title="Sim-to-real gap report")
    paths["html"] = write_bytes_atomic(out / REPORT_FILES["html"], page.encode())
    for name, data in extras.items():
        paths[name] = write_bytes_atomic(out / name, bytes(data))
    return paths
