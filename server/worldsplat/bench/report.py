"""The report model: sections of measured rows, written as one markdown page with PNG plots."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path

from worldsplat.core.io import atomic_write_bytes


@dataclass
class Pareto:
    """A speed-vs-error plot: one point per setting, the default marked."""

    x_label: str  # usually a cost (seconds, bytes, Gaussians)
    y_label: str  # usually an error or a quality (PSNR)
    points: list[tuple[str, float, float]]  # (setting, x, y)
    default: str
    log_x: bool = False
    curve: bool = True  # the points are one knob's settings in order (joined by a line); False: separate things


@dataclass
class Section:
    key: str
    title: str
    columns: list[str]
    rows: list[list[object]]
    default: str = ""
    why: str = ""
    pareto: Pareto | None = None
    notes: list[str] = field(default_factory=list)
    data: dict = field(default_factory=dict)  # raw numbers for checks


def fmt(v: object) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        a = abs(v)
        if a != 0 and (a < 1e-3 or a >= 1e5):
            return f"{v:.3g}"
        return f"{v:.4g}" if a < 100 else f"{v:.1f}"
    return str(v)


def plot_pareto(p: Pareto, path: Path) -> None:
    import matplotlib  # noqa: PLC0415 - matplotlib, only for plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - matplotlib, only for plots

    fig, ax = plt.subplots(figsize=(5, 3.4), dpi=110)
    xs = [x for _, x, _ in p.points]
    ys = [y for _, _, y in p.points]
    ax.plot(xs, ys, "o-" if p.curve else "o", color="#4477aa", lw=1.2, ms=4)
    for name, x, y in p.points:
        is_default = name == p.default
        ax.annotate(
            name,
            (x, y),
            fontsize=7,
            xytext=(3, 3),
            textcoords="offset points",
            color="#cc3311" if is_default else "#333333",
            weight="bold" if is_default else None,
        )
        if is_default:
            ax.plot([x], [y], "*", color="#cc3311", ms=12, label=f"default: {name}")
    if p.log_x:
        ax.set_xscale("log")
    else:  # at most 6 ticks: close values (0.0950, 0.0975, ...) otherwise run into each other
        ax.xaxis.set_major_locator(plt.MaxNLocator(6))
    ax.set_xlabel(p.x_label)
    ax.set_ylabel(p.y_label)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    atomic_write_bytes(path, _fig_bytes(fig))
    plt.close(fig)


def _fig_bytes(fig) -> bytes:

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def write_report(sections: list[Section], out: Path, header: list[str]) -> Path:
    lines = ["# Speed against error", "", *header, ""]
    lines += ["| section | default | why (short) |", "|---|---|---|"]
    for s in sections:
        lines.append(f"| [{s.title}](#{s.key}) | {s.default} | {s.why.split('. ')[0]} |")
    for s in sections:
        lines += ["", f"<a id=\"{s.key}\"></a>", f"## {s.title}", ""]
        lines.append("| " + " | ".join(s.columns) + " |")
        lines.append("|" + "---|" * len(s.columns))
        for r in s.rows:
            lines.append("| " + " | ".join(fmt(v) for v in r) + " |")
        if s.pareto is not None:
            png = f"{s.key}.png"
            plot_pareto(s.pareto, out / png)
            lines += ["", f"![{s.title}]({png})"]
        if s.default:
            lines += ["", f"**Default: {s.default}.** {s.why}"]
        for n in s.notes:
            lines += ["", n]
    path = out / "report.md"
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
    return path
