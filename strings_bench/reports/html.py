"""The run's report as static HTML: `report/index.html` and one word-crop gallery page per scene.

Size (~680 lines): one offline page generator; its CSS, script and gallery are inline by design (no CDN, no template files to lose).

    from strings_bench.reports.html import write_html    # called by write_report

Offline from the file system: no server, no CDN, no external script; CSS and a small vanilla
script are inline. Everything shown comes from the run folder:

- `index.html`: the run's configuration (run.json), every table of the report (the same `Table`
  objects as the LaTeX/Markdown/CSV files; sortable by clicking a column header; the paper's
  first/second/third shading), every figure (relative links to `figures/`), the list of scene
  galleries, and every results.csv row (sortable, paginated; any extra column, e.g. a second OCR
  engine's CER, is shown as it is);
- `gallery/<dataset>/<scene>/index.html`: per checkpoint, every reference word of the word-crop
  readability metric (strings_bench.eval.readability): its GT crop and each method's render crop
  side by side, what the recogniser read on each and the per-word error (edit errors over the
  reference characters, both normalised). The crops are written during report generation from
  the saved renders and GT views (`gallery/<dataset>/<scene>/crops/`), rectified exactly as the
  metric rectified them (the stored word box and turn), and kept while their source is unchanged.

Pages stay fast with thousands of crops: each scene is its own page, one checkpoint is shown at a
time, rows are paginated, and images are `loading="lazy"` (hidden rows are never fetched). All
text is HTML-escaped (OCR output is untrusted).
"""

from __future__ import annotations

import hashlib
import html
import io
import json
import logging
import math
import numbers
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pandas as pd

from strings_bench.reports.ablations import AblationTable, fmt3
from strings_bench.reports.table_model import GT_CEILING, REGISTERED, MethodNames, Table, dataset_title, label_value
from strings_bench.store import RESULT_FILE, CellKey, render_file_name, safe_name
from strings_bench.core.io import atomic_write, atomic_write_text

__all__ = ["write_html", "table_html", "GALLERY_PAGE_SIZE", "CELLS_PAGE_SIZE"]

log = logging.getLogger(__name__)

GALLERY_PAGE_SIZE = 40  # reference words per gallery page
CELLS_PAGE_SIZE = 25  # results.csv rows per page on the index
CROP_MAX_WIDTH = 320  # CSS pixels; crops are the recogniser's 48-pixel-high input, long words are scaled down

CSS = """
:root { --first: rgb(242,182,181); --second: rgb(249,218,184); --third: rgb(254,250,199); --line: #d0d0d0; }
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0; color: #222; background: #fff; }
header, main { max-width: 1400px; margin: 0 auto; padding: 0 20px; }
header { border-bottom: 1px solid var(--line); padding-top: 8px; }
nav a { margin-right: 14px; }
h1 { font-size: 22px; margin: 10px 0 6px; } h2 { font-size: 18px; margin-top: 28px; border-bottom: 1px solid var(--line); }
h3 { font-size: 15px; margin: 18px 0 6px; }
table.data { border-collapse: collapse; margin: 6px 0; font-variant-numeric: tabular-nums; }
table.data th, table.data td { border: 1px solid var(--line); padding: 3px 7px; text-align: center; vertical-align: middle; }
table.data td.name, table.data th.name { text-align: left; }
table.data thead th { background: #f4f4f4; }
th.sortable { cursor: pointer; user-select: none; white-space: nowrap; }
th.sortable::after { content: " \\2195"; color: #999; }
th[aria-sort="ascending"]::after { content: " \\25B2"; color: #333; }
th[aria-sort="descending"]::after { content: " \\25BC"; color: #333; }
td.greyed { color: #9a9a9a; background: #f2f2f2; font-style: italic; } td.first { background: var(--first); } td.second { background: var(--second); } td.third { background: var(--third); }
tr.ceiling td { font-style: italic; color: #555; background: #fafafa; }
td.best { font-weight: bold; }
td.decided { font-weight: 600; color: #1a6d1a; } td.undecided { color: #9a5b00; }
.caption { color: #555; max-width: 1000px; font-size: 13px; }
.legend span { padding: 1px 8px; margin-right: 6px; border: 1px solid var(--line); }
.note { background: #fff6e0; border-left: 4px solid #e0a000; padding: 4px 10px; }
dl.config { display: grid; grid-template-columns: max-content auto; gap: 2px 16px; }
dl.config dt { font-weight: 600; } dl.config dd { margin: 0; }
pre { background: #f7f7f7; padding: 8px; overflow-x: auto; font-size: 12px; }
figure { display: inline-block; margin: 8px 12px 8px 0; vertical-align: top; }
figure img { max-width: 640px; border: 1px solid var(--line); }
figcaption { font-size: 12px; color: #555; }
.pager { margin: 4px 0 14px; } .pager button { margin-right: 6px; }
.tabs button { margin: 0 4px 6px 0; padding: 3px 10px; } .tabs button.active { font-weight: bold; background: #dde8ff; }
table.gallery td { min-width: 90px; }
table.gallery img { display: block; margin: 0 auto; max-width: %dpx; height: auto; image-rendering: auto; }
.read { font-family: ui-monospace, "DejaVu Sans Mono", monospace; font-size: 12px; }
.err { font-size: 12px; } td.exact { background: #e3f4e3; } td.wrong { background: #fbe4e4; }
.empty { color: #999; font-style: italic; }
.muted { color: #777; font-size: 12px; }
.scroll { overflow-x: auto; max-width: 100%%; }
""" % CROP_MAX_WIDTH

# Sorting by a header click (numbers by data-v, n/a last either way), pagination of tables with
# data-page-size, and checkpoint tabs. No library: the page must open from file:// with no network.
JS = r"""
(function () {
  "use strict";
  function key(td, type) {
    if (!td) return null;
    var v = td.hasAttribute("data-v") ? td.getAttribute("data-v") : td.textContent.trim();
    if (type === "num") { var x = parseFloat(v); return (v === "" || isNaN(x)) ? null : x; }
    return v === "" ? null : v.toLowerCase();
  }
  function setup(table) {
    var body = table.tBodies[0];
    if (!body) return;
    var rows = Array.prototype.slice.call(body.rows);
    rows.forEach(function (r, i) { r.setAttribute("data-i", String(i)); });
    var size = parseInt(table.getAttribute("data-page-size") || "0", 10);
    var page = 0, pager = null, info = null, prev = null, next = null;
    function pages() { return size > 0 ? Math.max(1, Math.ceil(rows.length / size)) : 1; }
    function show() {
      rows.forEach(function (r, i) { r.hidden = size > 0 && (i < page * size || i >= (page + 1) * size); });
      if (pager) {
        var first = rows.length ? page * size + 1 : 0, last = Math.min(rows.length, (page + 1) * size);
        info.textContent = "rows " + first + "\u2013" + last + " of " + rows.length + " (page " + (page + 1) + " of " + pages() + ")";
        prev.disabled = page === 0; next.disabled = page >= pages() - 1;
      }
    }
    if (size > 0 && rows.length > size) {
      pager = document.createElement("div"); pager.className = "pager";
      prev = document.createElement("button"); prev.type = "button"; prev.textContent = "\u25C0 previous";
      next = document.createElement("button"); next.type = "button"; next.textContent = "next \u25B6";
      info = document.createElement("span");
      prev.addEventListener("click", function () { if (page > 0) { page--; show(); } });
      next.addEventListener("click", function () { if (page < pages() - 1) { page++; show(); } });
      pager.appendChild(prev); pager.appendChild(next); pager.appendChild(info);
      table.parentNode.insertBefore(pager, table.nextSibling);
    }
    var heads = table.querySelectorAll("th[data-col]");
    Array.prototype.forEach.call(heads, function (th) {
      th.classList.add("sortable");
      th.setAttribute("title", "sort by this column");
      th.addEventListener("click", function () {
        var col = parseInt(th.getAttribute("data-col"), 10), type = th.getAttribute("data-type") || "text";
        var dir = th.getAttribute("aria-sort") === "ascending" ? -1 : 1;
        Array.prototype.forEach.call(heads, function (h) { h.removeAttribute("aria-sort"); });
        th.setAttribute("aria-sort", dir === 1 ? "ascending" : "descending");
        rows.sort(function (a, b) {
          var ka = key(a.cells[col], type), kb = key(b.cells[col], type);
          if (ka === null || kb === null) {
            if (ka === kb) return parseInt(a.getAttribute("data-i"), 10) - parseInt(b.getAttribute("data-i"), 10);
            return ka === null ? 1 : -1;
          }
          if (ka < kb) return -dir;
          if (ka > kb) return dir;
          return parseInt(a.getAttribute("data-i"), 10) - parseInt(b.getAttribute("data-i"), 10);
        });
        rows.forEach(function (r) { body.appendChild(r); });
        page = 0; show();
      });
    });
    show();
  }
  Array.prototype.forEach.call(document.querySelectorAll("table.data"), setup);
  Array.prototype.forEach.call(document.querySelectorAll(".tabs"), function (tabs) {
    var buttons = tabs.querySelectorAll("button[data-panel]");
    function activate(btn) {
      Array.prototype.forEach.call(buttons, function (b) {
        var on = b === btn;
        b.classList.toggle("active", on);
        var panel = document.getElementById(b.getAttribute("data-panel"));
        if (panel) panel.hidden = !on;
      });
    }
    Array.prototype.forEach.call(buttons, function (b) { b.addEventListener("click", function () { activate(b); }); });
    var start = tabs.querySelector("button.active") || buttons[buttons.length - 1];
    if (start) activate(start);
  });
})();
"""


def esc(x) -> str:
    """HTML-escape any value (quotes too, so it is safe in attributes)."""
    return html.escape("" if x is None else str(x), quote=True)


def href(path: str | Path) -> str:
    """A relative link to a file: URL-quoted (POSIX separators) and HTML-escaped."""
    return esc(quote(Path(path).as_posix()))


def _is_nan(x) -> bool:
    return x is None or (isinstance(x, numbers.Real) and math.isnan(float(x)))


def sort_key(v) -> str:
    """A number as the page's script sorts it (data-v): "" for n/a, JavaScript's spelling of infinities."""
    if _is_nan(v):
        return ""
    f = float(v)
    if math.isinf(f):
        return "Infinity" if f > 0 else "-Infinity"
    return repr(f)


def _number(v) -> str:
    """A results.csv number as shown: integers as they are, other floats to 4 significant digits."""
    f = float(v)
    if math.isinf(f):
        return "inf" if f > 0 else "-inf"
    return str(int(f)) if f.is_integer() else f"{f:.4g}"


def _plain(s: str) -> str:
    """Caption text of the LaTeX tables, readable as plain text (they are plain apart from escapes)."""
    for a, b in ((r"\_", "_"), (r"\&", "&"), (r"\%", "%"), (r"\$", "$"), (r"\#", "#"), (r"\{", "{"), (r"\}", "}"),
                 (r"\textasciitilde{}", "~"), (r"\textasciicircum{}", "^"), (r"\textbackslash{}", "\\")):
        s = s.replace(a, b)
    return s


def html_page(title: str, body: str, back: str | None = None) -> str:
    nav = f'<header><p><a href="{href(back)}">&larr; back to the report</a></p></header>' if back else ""
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{esc(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n"
            f"{nav}{body}\n<script>{JS}</script>\n</body>\n</html>\n")


# ---- tables ------------------------------------------------------------------------------------------
def table_html(t: Table) -> str:
    """One report table as a sortable HTML table: a row per method, a column per Column, the best three
    of each column with class first/second/third (Table.shading, as in the LaTeX), n/a never ranked."""
    if isinstance(t, AblationTable):
        return _ablation_html(t)
    groups: list[tuple[str, int]] = []
    for c in t.columns:
        if groups and groups[-1][0] == c.group:
            groups[-1] = (c.group, groups[-1][1] + 1)
        else:
            groups.append((c.group, 1))
    out = [f'<table class="data report-table" id="table-{esc(t.name)}" data-table="{esc(t.name)}">', "<thead>"]
    has_groups = any(g for g, _ in groups)
    rowspan = ' rowspan="2"' if has_groups else ""
    corner = f'<th class="name" data-col="0" data-type="text"{rowspan}>{esc(t.corner_plain)}</th>'
    if has_groups:
        out.append("<tr>" + corner + "".join(f'<th colspan="{n}">{esc(g)}</th>' for g, n in groups) + "</tr>")
        out.append("<tr>" + "".join(f'<th data-col="{i + 1}" data-type="num">{esc(c.sub_plain)}</th>'
                                    for i, c in enumerate(t.columns)) + "</tr>")
    else:
        out.append("<tr>" + corner + "".join(f'<th data-col="{i + 1}" data-type="num">{esc(c.sub_plain)}</th>'
                                             for i, c in enumerate(t.columns)) + "</tr>")
    out += ["</thead>", "<tbody>"]
    shades = [t.shading(c) for c in t.columns]
    for m in t.methods:
        cls = ' class="ceiling"' if m == GT_CEILING else ""
        cells = [f'<td class="name" data-method="{esc(m)}">{esc(t.names.title(m))}</td>']
        for c, sh in zip(t.columns, shades):
            v = c.values.get(m, math.nan)
            rank = sh.get(m)
            data_v = sort_key(v)
            klass = "greyed" if c.greyed else rank
            cells.append(f'<td{f" class={chr(34)}{klass}{chr(34)}" if klass else ""} data-v="{esc(data_v)}">'
                         f"{esc(t.fmt(c, v, m))}</td>")
        out.append(f"<tr{cls}>" + "".join(cells) + "</tr>")
    out += ["</tbody>", "</table>"]
    return "\n".join(out)


def _ablation_html(t: AblationTable) -> str:
    datasets = t.datasets
    head = ['<th class="name" data-col="0" data-type="text">Ablation</th>', '<th data-col="1" data-type="text">Checkpoint</th>']
    col = 2
    for d in datasets:
        for side in ("w/o", "Ours"):
            head.append(f'<th data-col="{col}" data-type="num">{esc(dataset_title(d))} {esc(side)}</th>')
            col += 1
    out = [f'<table class="data report-table" id="table-{esc(t.name)}" data-table="{esc(t.name)}">',
           "<thead><tr>" + "".join(head) + "</tr></thead>", "<tbody>"]
    for title, _abl, label, vals in t.rows:
        cells = [f'<td class="name">{esc(title)}</td>', f"<td>{esc(label)}</td>"]
        for wo, ours in vals:
            better_wo = not (_is_nan(wo) or _is_nan(ours)) and round(wo, 3) < round(ours, 3)
            better_ours = not (_is_nan(wo) or _is_nan(ours)) and round(ours, 3) < round(wo, 3)
            for v, best in ((wo, better_wo), (ours, better_ours)):
                data_v = sort_key(v)
                cells.append(f'<td{" class=" + chr(34) + "best" + chr(34) if best else ""} data-v="{esc(data_v)}">'
                             f"{esc(fmt3(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out += ["</tbody>", "</table>"]
    return "\n".join(out)


def _cells_table(df: pd.DataFrame) -> str:
    """Every results.csv row and column (sortable, paginated)."""
    cols = list(df.columns)
    numeric = {c: pd.api.types.is_numeric_dtype(df[c]) for c in cols}
    head = "".join(f'<th data-col="{i}" data-type="{"num" if numeric[c] else "text"}">{esc(c)}</th>'
                   for i, c in enumerate(cols))
    out = [f'<table class="data" id="table-cells" data-page-size="{CELLS_PAGE_SIZE}">', f"<thead><tr>{head}</tr></thead>",
           "<tbody>"]
    for row in df.itertuples(index=False):
        cells = []
        for c, v in zip(cols, row):
            if numeric[c]:
                if _is_nan(v):
                    cells.append('<td data-v="">n/a</td>')
                else:
                    cells.append(f'<td data-v="{esc(sort_key(v))}">{esc(_number(v))}</td>')
            else:
                cells.append(f"<td>{'' if _is_nan(v) else esc(v)}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out += ["</tbody>", "</table>"]
    return "\n".join(out)


# ---- configuration ---------------------------------------------------------------------------------------
def _config_html(manifest: dict, run_dir: Path, n_cells: int) -> str:
    if not manifest:
        return '<p class="note">This run folder has no run.json: its configuration is unknown.</p>'
    schedule = manifest.get("schedule") or {}
    rows: list[tuple[str, str]] = [("run folder", str(run_dir.resolve())), ("cells", str(n_cells))]
    if schedule:
        rows.append(("schedule", f"{schedule.get('name')} (steps scale {schedule.get('steps_scale')}): "
                                 f"{schedule.get('description', '')}"))
        if schedule.get("paper_checkpoints"):
            rows.append(("checkpoints (paper iterations)", ", ".join(str(c) for c in schedule["paper_checkpoints"])))
    for key in ("downscale", "ocr", "cer_profile", "device", "save_every"):
        if manifest.get(key) not in (None, ""):
            rows.append((key.replace("_", " "), str(manifest[key])))
    if manifest.get("resolved_device"):
        d = manifest["resolved_device"]
        rows.append(("ran on", f"{d.get('device', '')} {d.get('gpu') or ''}".strip()))
    if manifest.get("datasets"):
        rows.append(("datasets", ", ".join(str(d) for d in manifest["datasets"])))
    body = "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>" for k, v in rows)
    methods = manifest.get("methods") or {}
    overrides = manifest.get("method_overrides") or {}
    mrows = []
    for m, info in methods.items():
        sets = overrides.get(m) or {}
        mrows.append(f'<tr><td class="name">{esc(m)}</td><td class="name">{esc(info.get("paper", ""))}</td>'
                     f'<td class="name">{esc(info.get("description", ""))}</td>'
                     f'<td class="name">{esc(", ".join(f"{k}={v}" for k, v in sets.items()))}</td></tr>')
    mtable = ""
    if mrows:
        mtable = ('<h3>Methods</h3><table class="data" id="table-methods"><thead><tr>'
                  '<th class="name" data-col="0" data-type="text">method</th><th class="name">paper</th>'
                  '<th class="name">description</th><th class="name">--set values</th></tr></thead><tbody>'
                  + "".join(mrows) + "</tbody></table>")
    versions = manifest.get("versions") or {}
    vline = f'<p class="muted">versions: {esc(", ".join(f"{k} {v}" for k, v in versions.items()))}</p>' if versions else ""
    full = json.dumps(manifest, indent=2, sort_keys=True, default=str)
    return (f'<dl class="config">{body}</dl>{mtable}{vline}'
            f"<details><summary>run.json</summary><pre>{esc(full)}</pre></details>")


# ---- word crops ---------------------------------------------------------------------------------------------
@dataclass
class GalleryWord:
    """One reference word of a scene's test view, with what each cell's recogniser read on it."""

    view: str
    text: str
    source: str
    headline: bool
    quad: list
    turn: int
    chars: int
    gt: dict  # {"read", "nll", "errors"} on the GT view
    renders: dict = field(default_factory=dict)  # (method, label) -> {"read", "nll", "errors", "iteration"}

    @property
    def crop_name(self) -> str:
        """A file name that changes when the word's box, turn or the crop geometry does."""
        from strings_bench.eval.readability import CROP_MARGIN, REC_HEIGHT

        key = json.dumps([self.view, self.text, np.round(np.asarray(self.quad, float), 3).tolist(), self.turn,
                          REC_HEIGHT, CROP_MARGIN])
        return hashlib.sha1(key.encode("utf-8")).hexdigest()[:16] + ".png"


@dataclass
class SceneGallery:
    """Every reference word of one (dataset, scene) over its cells, and where the crops go."""

    dataset: str
    scene: str
    words: dict = field(default_factory=dict)  # word key -> GalleryWord, in first-seen order
    cells: dict = field(default_factory=dict)  # (method, label) -> iteration
    missing_readability: list = field(default_factory=list)  # (method, label) whose cell has no word-crop metric

    @property
    def folder(self) -> Path:
        return Path("gallery") / safe_name(self.dataset) / safe_name(self.scene)


def _word_key(view: str, rec: dict) -> tuple:
    # The source is part of the key: a GT-OCR word over a known word is a reference word of its own
    # (outside the headline figures), shown on its own row even where its box and text are the same.
    return view, str(rec.get("source", "")), str(rec.get("text", "")), tuple(np.round(np.asarray(rec.get("polygon", []), float), 2).ravel().tolist())


def collect_galleries(run_dir: Path, df: pd.DataFrame) -> list[SceneGallery]:
    """The reference words of every (dataset, scene) in results.csv, read from the cells' result.json
    (`readability.views`), with each (method, checkpoint label)'s reading of each word."""
    out: dict[tuple[str, str], SceneGallery] = {}
    if df.empty:
        return []
    rows = df.sort_values(["dataset", "scene", "iteration"], kind="stable")
    if "evaluation" in rows:  # the dense checkpoints of `every:N` get no gallery tab (there may be dozens)
        rows = rows[rows["evaluation"].fillna("full") != "words"]
    for r in rows.itertuples(index=False):
        g = out.setdefault((r.dataset, r.scene), SceneGallery(str(r.dataset), str(r.scene)))
        path = CellKey(str(r.method), str(r.dataset), str(r.scene), int(r.iteration)).path(run_dir) / RESULT_FILE
        try:
            rec = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue  # results.csv is rebuilt from the cells first; a vanished cell is simply not shown
        label = str(r.label)
        views = (rec.get("readability") or {}).get("views")
        g.cells[(str(r.method), label)] = int(r.iteration)
        if not views:
            g.missing_readability.append((str(r.method), label))
            continue
        for view, records in views.items():
            for w in records or []:
                k = _word_key(view, w)
                if k not in g.words:
                    g.words[k] = GalleryWord(view, str(w.get("text", "")), str(w.get("source", "")),
                                             bool(w.get("headline", True)), w.get("polygon") or [], int(w.get("turn") or 0),
                                             int(w.get("chars") or 0), dict(w.get("gt") or {}))
                g.words[k].renders[(str(r.method), label)] = {**(w.get("render") or {}), "iteration": int(r.iteration)}
    return [g for g in out.values() if g.cells]  # a scene none of whose cells could be read has no page


def _load_rgb(path: Path) -> np.ndarray | None:
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (OSError, ValueError):
        return None


def _write_crop(dst: Path, img: np.ndarray, word: GalleryWord, src: Path) -> bool:
    """Rectify `word` out of `img` into `dst` (atomically) unless `dst` is newer than `src`; False when the
    word's box is unusable."""
    from PIL import Image

    from strings_bench.eval.readability import rectify

    if dst.exists() and dst.stat().st_mtime >= src.stat().st_mtime:
        return True
    quad = np.asarray(word.quad, dtype=np.float64)
    if quad.shape != (4, 2) or not np.all(np.isfinite(quad)):
        return False
    crop = rectify(img, quad, turn=word.turn)
    buf = io.BytesIO()
    Image.fromarray(crop).save(buf, format="PNG", optimize=False)
    data = buf.getvalue()
    atomic_write(dst, lambda p: p.write_bytes(data))
    return True


class _Images:
    """Source images (GT views, renders) loaded once each while a scene's crops are written."""

    def __init__(self):
        self._cache: dict[Path, np.ndarray | None] = {}

    def get(self, path: Path) -> np.ndarray | None:
        if path not in self._cache:
            self._cache[path] = _load_rgb(path) if path.is_file() else None
        return self._cache[path]


def write_crops(run_dir: Path, out: Path, g: SceneGallery) -> dict:
    """Write the scene's crops under out/<g.folder>/crops/ (GT once per word, one per (method, checkpoint)
    and word); stale crops of words no longer present are removed. Returns {(side, word key): relative
    path or None} where side is "gt" or (method, label)."""
    base = out / g.folder
    crops_root = base / "crops"
    images = _Images()
    paths: dict = {}
    keep: set[Path] = set()
    gt_dir = run_dir / "gt" / safe_name(g.dataset) / safe_name(g.scene)
    for k, w in g.words.items():
        stem = Path(render_file_name(w.view)).stem
        src = gt_dir / render_file_name(w.view)
        img = images.get(src)
        rel = Path("crops") / "gt" / safe_name(stem) / w.crop_name
        ok = img is not None and _write_crop(base / rel, img, w, src)
        paths[("gt", k)] = rel if ok else None
        if ok:
            keep.add(base / rel)
        for (method, label), reading in w.renders.items():
            it = reading["iteration"]
            src = CellKey(method, g.dataset, g.scene, it).path(run_dir) / "renders" / render_file_name(w.view)
            img = images.get(src)
            rel = Path("crops") / safe_name(method) / str(it) / safe_name(stem) / w.crop_name
            ok = img is not None and _write_crop(base / rel, img, w, src)
            paths[((method, label), k)] = rel if ok else None
            if ok:
                keep.add(base / rel)
    if crops_root.is_dir():
        for p in crops_root.rglob("*.png"):
            if p not in keep:
                p.unlink(missing_ok=True)
    return paths


def _reading_cell(reading: dict | None, chars: int, crop: Path | None, alt: str) -> str:
    """A gallery cell: the crop, what was read, and the per-word error (data-v: errors / chars)."""
    if reading is None:
        return '<td data-v=""><span class="empty">no cell</span></td>'
    errors = reading.get("errors")
    cer = errors / chars if errors is not None and chars else None
    cls = "" if cer is None else (" exact" if errors == 0 else (" wrong" if cer >= 1 else ""))
    img = (f'<img src="{href(crop)}" loading="lazy" alt="{esc(alt)}">' if crop is not None
           else '<span class="empty">image missing</span>')
    read = reading.get("read") or ""
    read_html = f'<span class="read">{esc(read)}</span>' if read else '<span class="empty">(nothing read)</span>'
    err = "n/a" if cer is None else f"{errors}/{chars} errors (CER {cer:.2f})"
    nll = reading.get("nll")
    title = "" if _is_nan(nll) else f' title="text NLL {esc(f"{float(nll):.3g}")} nats"'
    return (f'<td class="crop{cls}" data-v="{esc(sort_key(cer))}"{title}>{img}'
            f'<div>{read_html}</div><div class="err">{esc(err)}</div></td>')


def gallery_page(g: SceneGallery, paths: dict, back: str, names: MethodNames = REGISTERED) -> str:
    """The HTML of one scene's word-crop gallery: a tab per checkpoint label, a row per reference word."""
    labels = sorted({label for _m, label in g.cells}, key=label_value)
    methods = names.order(m for m, _l in g.cells)
    title = f"Word crops: {dataset_title(g.dataset)} / {g.scene}"
    parts = [f"<header><h1>{esc(title)}</h1></header><main>",
             f"<p>{len(g.words)} reference word(s) over the scene's test views; for each, the ground-truth view's crop "
             "and every method's render crop, rectified to the recogniser's input as the word-crop readability metric "
             "reads them (docs/ocr.md). Under each crop: what the recogniser read, and the word's edit errors over its "
             "reference characters (both lower-cased, spaces removed). Green: read exactly; red: CER 1 or more. "
             "Click a column header to sort the words by it.</p>"]
    if g.missing_readability:
        parts.append('<p class="note">No word-crop readability in the cell(s) '
                     + esc(", ".join(f"{m} @{l}" for m, l in g.missing_readability))
                     + " (the recogniser could not load when they were evaluated).</p>")
    if not g.words:
        parts.append('<p class="note">This scene has no reference words (no legible known text and nothing read on '
                     "the GT views), so there is nothing to show.</p>")
        return html_page(title, "\n".join(parts) + "</main>", back)
    parts.append('<div class="tabs">' + "".join(
        f'<button type="button" data-panel="ckpt-{i}"{" class=" + chr(34) + "active" + chr(34) if i == len(labels) - 1 else ""}>'
        f"{esc(label)}</button>" for i, label in enumerate(labels)) + "</div>")
    for i, label in enumerate(labels):
        here = [m for m in methods if (m, label) in g.cells]
        its = ", ".join(f"{m}: {g.cells[(m, label)]}" for m in here)
        head = ['<th class="name" data-col="0" data-type="text">view</th>',
                '<th class="name" data-col="1" data-type="text">reference word</th>',
                '<th data-col="2" data-type="num">ground truth</th>']
        head += [f'<th data-col="{3 + j}" data-type="num">{esc(names.title(m))}</th>' for j, m in enumerate(here)]
        rows = []
        for k, w in g.words.items():
            src = esc(w.source) + ("" if w.headline else " (same word as a known one; not in the headline figures)")
            cells = [f'<td class="name">{esc(Path(w.view).stem)}</td>',
                     f'<td class="name" data-v="{esc(w.text)}"><span class="read">{esc(w.text)}</span>'
                     f'<div class="muted">{src}</div></td>',
                     _reading_cell(w.gt, w.chars, paths.get(("gt", k)), f"GT crop of {w.text}")]
            for m in here:
                cells.append(_reading_cell(w.renders.get((m, label)), w.chars, paths.get(((m, label), k)),
                                           f"{m} crop of {w.text}"))
            rows.append("<tr>" + "".join(cells) + "</tr>")
        parts.append(f'<section id="ckpt-{i}" class="checkpoint" data-label="{esc(label)}">'
                     f"<h2>Checkpoint {esc(label)}</h2><p class=\"muted\">iterations trained: {esc(its)}</p>"
                     f'<table class="data gallery" id="gallery-{i}" data-page-size="{GALLERY_PAGE_SIZE}"><thead><tr>{"".join(head)}</tr></thead>'
                     f"<tbody>{''.join(rows)}</tbody></table></section>")
    return html_page(title, "\n".join(parts) + "</main>", back)


def _fronts_html(fronts: list[dict], names: MethodNames = REGISTERED) -> str:
    """The fronts of one x axis (all of `fronts` share it) as a table: one row per (checkpoint, metric), the front's
    methods. Against training time: the speed/accuracy front; against the Gaussian count: the size/accuracy front."""
    from strings_bench.reports.readability_analysis import FRONT_METRICS, front_member

    x = fronts[0].get("x", "minutes") if fronts else "minutes"
    rows = []
    for f in fronts:
        members = "; ".join(front_member(f, m, names, metric_name=False) for m in f["front"])
        rows.append(f'<tr><td class="name">{esc(f["label"])}</td><td class="name">{esc(FRONT_METRICS[f["metric"]])}</td>'
                    f'<td class="name" data-front="{esc(",".join(f["front"]))}">{esc(members or "none")}</td></tr>')
    if x == "minutes":
        anchor, table_id, title, csv = "h-pareto_front", "table-pareto-front", "Speed/accuracy front", "pareto_front.csv"
        what, axis = "mean training time (preprocessing + optimisation)", "mean training minutes"
        where = "circled in the scatter figures"
    else:
        anchor, table_id, title, csv = "h-size_front", "table-size-front", "Size/accuracy front", "size_front.csv"
        what, axis = "mean Gaussian count at the checkpoint", "mean Gaussians"
        where = "circled in the CER-vs-Gaussians figures; an equal-budget run (run --budget) holds the counts level"
    return (f'<h3 id="{anchor}">{title}</h3><table class="data" id="{table_id}"><thead><tr>'
            '<th class="name" data-col="0" data-type="text">checkpoint</th><th class="name" data-col="1" data-type="text">'
            f'metric</th><th class="name" data-col="2" data-type="text">front ({axis}, mean CER)</th>'
            "</tr></thead><tbody>" + "".join(rows) + '</tbody></table><p class="caption">The methods that no other '
            f"method beats on both {what} and mean CER over the scenes; {where}. "
            f'CSV: <a href="tables/{csv}">tables/{csv}</a>.</p>')


# ---- the index -------------------------------------------------------------------------------------------------
def write_html(run_dir: str | Path, out: str | Path, df: pd.DataFrame, manifest: dict, tables: list[Table],
               figures: dict[str, Path], notes: list[str] | None = None, fronts: list[dict] | None = None) -> Path:
    """Write out/index.html and out/gallery/<dataset>/<scene>/ (pages and crops); returns index.html's path.

    tables: the report's Table objects (tables.build_tables); figures: name -> PNG path under `out`;
    notes: plain-text remarks shown under the title (OCR failures, LPIPS n/a, ...); fronts: the speed/accuracy
    fronts (readability_analysis.fronts), listed under the figures.
    """
    run_dir, out = Path(run_dir), Path(out)
    names = MethodNames.of(manifest)  # methods named as the run recorded them
    out.mkdir(parents=True, exist_ok=True)
    title = f"strings-bench report: {run_dir.resolve().name}"
    sections = [("config", "Configuration"), ("tables", "Tables"), ("figures", "Figures"), ("galleries", "Word crops"),
                ("cells", "All cells")]
    parts = [f"<header><h1>{esc(title)}</h1><nav>"
             + "".join(f'<a href="#{a}">{esc(t)}</a>' for a, t in sections) + "</nav></header><main>"]
    for n in notes or []:
        parts.append(f'<p class="note">{esc(n)}</p>')

    parts.append(f'<h2 id="config">Configuration</h2>{_config_html(manifest, run_dir, len(df))}')

    parts.append('<h2 id="tables">Tables</h2><p class="legend"><span style="background:var(--first)">first</span>'
                 '<span style="background:var(--second)">second</span><span style="background:var(--third)">third</span>'
                 "best of each column (ties share a place; compared as printed; n/a never ranks). Click a header to sort. "
                 "The same tables as LaTeX, Markdown and CSV are in <code>tables/</code>.</p>")
    if not tables:
        parts.append('<p class="note">No finished cells yet.</p>')
    for t in tables:
        files = ", ".join(f'<a href="{href(Path("tables") / f"{t.name}.{ext}")}">{ext}</a>' for ext in ("tex", "md", "csv")
                          if (out / "tables" / f"{t.name}.{ext}").exists())
        parts.append(f'<h3 id="h-{esc(t.name)}">{esc(t.name.replace("_", " "))}</h3>{table_html(t)}'
                     f'<p class="caption">{esc(_plain(t.caption))}{" Files: " + files if files else ""}</p>')

    parts.append('<h2 id="figures">Figures</h2>')
    if not figures:
        parts.append("<p>No figures.</p>")
    for name, p in figures.items():
        rel = Path(p).relative_to(out) if Path(p).is_absolute() else Path(p)
        # Figures load eagerly (a dozen at most); the thousands of crops are the lazy ones.
        parts.append(f'<figure><img src="{href(rel)}" alt="{esc(name)}">'
                     f"<figcaption>{esc(name.replace('_', ' '))}</figcaption></figure>")

    for x in dict.fromkeys(f.get("x", "minutes") for f in fronts or []):
        parts.append(_fronts_html([f for f in fronts if f.get("x", "minutes") == x], names))

    parts.append('<h2 id="galleries">Word crops</h2><p>Per scene, every reference word of the word-crop readability '
                 "metric: its ground-truth crop and each method's render crop side by side, per checkpoint, with what "
                 "the recogniser read on each. One page per scene:</p>")
    galleries = collect_galleries(run_dir, df)
    grow = []
    for g in galleries:
        page = g.folder / "index.html"
        t0 = time.perf_counter()
        paths = write_crops(run_dir, out, g)
        log.info("word crops of %s/%s: %d in %.1f s", g.dataset, g.scene, len(paths), time.perf_counter() - t0)
        back = "/".join([".."] * len(g.folder.parts)) + "/index.html"
        atomic_write_text(out / page, gallery_page(g, paths, back, names))
        n_crops = sum(p is not None for p in paths.values())
        views = len({w.view for w in g.words.values()})
        grow.append(f'<tr><td class="name">{esc(dataset_title(g.dataset))}</td>'
                    f'<td class="name"><a href="{href(page)}">{esc(g.scene)}</a></td>'
                    f'<td data-v="{views}">{views}</td><td data-v="{len(g.words)}">{len(g.words)}</td>'
                    f'<td data-v="{n_crops}">{n_crops}</td></tr>')
    if grow:
        parts.append('<table class="data" id="table-galleries"><thead><tr>'
                     '<th class="name" data-col="0" data-type="text">dataset</th>'
                     '<th class="name" data-col="1" data-type="text">scene</th>'
                     '<th data-col="2" data-type="num">views</th><th data-col="3" data-type="num">reference words</th>'
                     '<th data-col="4" data-type="num">crops</th></tr></thead><tbody>' + "".join(grow) + "</tbody></table>")
    else:
        parts.append("<p>No scenes yet.</p>")

    parts.append(f'<h2 id="cells">All cells</h2><p>Every row of <a href="{href(Path("..") / "results.csv")}">results.csv</a>, '
                 "one per (method, dataset, scene, checkpoint); docs/guide/run-folder.md lists the columns and their units.</p>")
    if not df.empty:
        parts.append(f'<div class="scroll">{_cells_table(df)}</div>')
    return atomic_write_text(out / "index.html", html_page(title, "\n".join(parts) + "</main>"))
