"""Generated tables in Markdown pages: every results table of the documentation is made from a CSV committed
beside it, so that a table cannot drift from its data.

A generated block in a page is an HTML comment naming its data, the table, and a closing comment:

    <!-- table (strings-bench docs refresh): data/default-run.csv kind=results columns=method,label,cer,cer_known -->
    | method | ckpt | OCR-CER | known-text CER |
    |---|---|---|---|
    ...
    <!-- end table -->

The path is relative to the page. `refresh_page` rewrites every block from its data; `strings-bench docs
refresh` does it for every page under `docs/` and the README, and `--check` fails where a page differs from
what its data gives (tests/docs/test_docs.py runs the check).

Kinds (`kind=`, default `csv`):

- `csv`: the CSV as it is, header and rows (for tables whose cells are already text); `columns=A,B` keeps those
  columns, in that order; `format=COLUMN:SPEC` (repeatable) writes that column's numbers with a Python format spec
  (`.2f`, `.1%`), for a machine-written CSV of full-precision floats;
- `text`: the `text` column of each row, as paragraphs (a paragraph a command writes, e.g. the README's on the
  paper's claims, from `strings-bench verdicts`);
- `results`: rows of a `results.csv` (the run folder's), the columns named by `columns=` with their usual
  headings and number formats; `bold=1` marks the best value of each readability column at each checkpoint
  (lowest CER, highest accuracy);
- `compare`: the long CSV `strings-bench compare` writes (method, label, value, mean, min, max, seeds, draws, ...):
  one row per method, one column per `values=` x `labels=` pair, each cell "mean (min-max)" (the range over the
  seeds and scene draws; none with one seed of one draw);
- `compare-table`: one of the tables `strings-bench compare` prints, made by compare's own formatter
  (`comparison_tables`) from the comparison.csv it banked: `table=compare_cer` (CER over seeds),
  `compare_time_quality` (training time and image quality) or `compare_ablations`;
- `markdown`: a table a command printed into a Markdown file it wrote (`strings-bench compare`'s comparison.md:
  its per-scene rows, the decisions, the tables over draws, which need the run folders' cells and are not in its
  CSV), as it was printed: `section=SLUG` names the `## ` heading (lower case, words joined by '-': `per-scene`,
  `decided-or-not`, `known-text-cer-over-draws`) whose first table it is.

Options common to all kinds: `where=COLUMN:VALUE[|VALUE...]` keeps the rows whose column is one of the values
(repeatable, comma-free values).
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_text

OPEN = "<!-- table (strings-bench docs refresh): "
CLOSE = "<!-- end table -->"
BLOCK_RE = re.compile(rf"(?P<open>{re.escape(OPEN)}(?P<spec>[^>]*?) -->\n)(?P<body>.*?)(?P<close>{re.escape(CLOSE)})", re.S)

# results.csv columns: heading, number format, and which way is better ("min", "max" or None).
RESULT_COLUMNS: dict[str, tuple[str, str, str | None]] = {
    "method": ("method", "s", None),
    "dataset": ("dataset", "s", None),
    "scene": ("scene", "s", None),
    "label": ("ckpt", "s", None),
    "iteration": ("steps", "int", None),
    "cer": ("OCR-CER", ".3f", "min"),
    "cer_known": ("known-text CER", ".3f", "min"),
    "word_cer": ("word CER", ".3f", "min"),
    "word_acc": ("word acc", ".3f", "max"),
    "text_nll": ("text NLL (nats/char)", ".2f", "min"),
    "text_psnr": ("text PSNR (dB)", ".2f", None),
    "psnr": ("PSNR (dB)", ".2f", None),
    "ssim": ("SSIM", ".3f", None),
    "lpips": ("LPIPS", ".3f", None),
    "gaussians": ("Gaussians", "int", None),
    "train_seconds": ("training (s)", ".0f", None),
    "total_seconds": ("total (s)", ".0f", None),
    "seed": ("seed", "s", None),
}

# compare's value names and their headings.
COMPARE_VALUES = {
    "cer": "OCR-CER", "cer_known": "known-text CER", "word_cer": "word CER", "word_acc": "word acc",
    "psnr": "PSNR", "ssim": "SSIM", "lpips": "LPIPS", "gaussians": "Gaussians", "train_minutes": "training (min)",
}


@dataclass
class Block:
    """One generated block of a page: its spec (the opening comment's text) and its current body."""

    spec: str
    body: str
    start: int
    end: int


def parse_spec(spec: str) -> tuple[str, dict[str, list[str]]]:
    """`"data/x.csv kind=results columns=a,b"` -> ("data/x.csv", {"kind": ["results"], "columns": ["a,b"]})."""
    words = spec.split()
    if not words:
        raise StringsBenchError("a table block names no data file", hint="<!-- table (strings-bench docs refresh): data/FILE.csv [kind=...] -->")
    options: dict[str, list[str]] = {}
    for word in words[1:]:
        key, eq, value = word.partition("=")
        if not eq:
            raise StringsBenchError(f"table option {word!r} is not KEY=VALUE")
        options.setdefault(key, []).append(value)
    return words[0], options


def read_csv(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        raise StringsBenchError(f"table data {path} does not exist")
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    header = reader.fieldnames or []
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:  # a dict row keeps the last of two equal names: a column would vanish and another shift into its place
        raise StringsBenchError(f"table data {path}: the header names {', '.join(map(repr, twice))} twice",
                                hint="give each column its own name")
    for n, row in enumerate(rows, start=2):
        if None in row:  # more fields than the header: an unquoted comma would shift every later column
            raise StringsBenchError(f"table data {path}, line {n}: {len(row) - 1 + len(row[None])} fields where the "
                                    f"header has {len(row) - 1} (a value with a comma must be quoted)")
    return rows


def _filter(rows: list[dict[str, str]], options: dict[str, list[str]], path: Path) -> list[dict[str, str]]:
    for cond in options.get("where", []):
        col, _, values = cond.partition(":")
        if rows and col not in rows[0]:
            raise StringsBenchError(f"{path}: where= names column {col!r}, which the CSV does not have")
        keep = set(values.split("|"))
        rows = [r for r in rows if r.get(col) in keep]
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def write_csv(path: Path, rows: list[list]) -> None:
    """Write rows (the header first) as CSV, atomically; csv quotes a value with a comma in it."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    atomic_write_text(path, buf.getvalue())


def show_and_save(rows: list[dict], path: Path | None) -> None:
    """Print dict rows as a Markdown table (columns: the first row's keys) and, with `path`, write them as the CSV
    a results page's table is generated from (atomic). The benchmarks' table output."""
    if not rows:
        print("(no rows)")
        return
    header = list(rows[0])
    print(markdown(header, [[str(r.get(h, "")) for h in header] for r in rows]), end="")
    if path is not None:
        write_csv(path, [header] + [[r.get(h, "") for h in header] for r in rows])


def set_table_column(table: Path, column: str, texts: dict[str, str], before: str | None = "flips?",
                     missing: str = "not measured") -> None:
    """Set (add or replace) the column `column` of a CSV table whose first column names its rows (a verdict table:
    one row per claim): row `key` gets texts[key], `missing` where texts has none. A new column goes before the
    column `before` when the table has it, else last. Written atomically."""
    with table.open(newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    if column in header:
        col = header.index(column)
    else:
        col = header.index(before) if before in header else len(header)
        header.insert(col, column)
        for row in body:
            row.insert(col, "")
    for row in body:
        row[col] = texts.get(row[0], missing)
    write_csv(table, [header] + body)


def _number(text: str) -> float | None:
    try:
        v = float(text)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(v) else v


def format_value(text: str, fmt: str) -> str:
    """A results.csv value in its column's format; an empty or NaN value is 'n/a'."""
    if fmt == "s":
        return text
    v = _number(text)
    if v is None:
        return "n/a" if text in ("", "nan", "NaN", "None") else text
    if fmt == "int":
        return f"{round(v):,}".replace(",", " ")
    return format(v, fmt)


def table_csv(rows: list[dict[str, str]], options: dict, path: Path) -> str:
    if not rows:
        raise StringsBenchError(f"{path} has no rows")
    header = ",".join(options["columns"]).split(",") if options.get("columns") else list(rows[0])
    formats = dict(f.partition(":")[::2] for f in options.get("format", []))
    for h in [*header, *formats]:
        if h not in rows[0]:
            raise StringsBenchError(f"{path} has no column {h!r}", hint=f"its columns: {', '.join(rows[0])}")

    def cell(r: dict, h: str) -> str:
        if h not in formats or _number(r[h]) is None:
            return r[h]
        try:
            return format(_number(r[h]), formats[h])
        except ValueError:
            raise StringsBenchError(f"{path}: format={h}:{formats[h]} is not a number format",
                                    hint="a Python format spec, e.g. .2f or .1%") from None

    return markdown(header, [[cell(r, h) for h in header] for r in rows])


def table_text(rows: list[dict[str, str]], options: dict, path: Path) -> str:
    if not rows or "text" not in rows[0]:
        raise StringsBenchError(f"{path}: kind=text needs a CSV with a 'text' column and a row")
    return "\n".join(r["text"] for r in rows) + "\n"


def table_results(rows: list[dict[str, str]], options: dict, path: Path) -> str:
    columns = ",".join(options.get("columns", [])).split(",") if options.get("columns") else []
    if not columns:
        raise StringsBenchError(f"{path}: kind=results needs columns=NAME,...")
    if not rows:
        raise StringsBenchError(f"{path} has no rows")
    for c in columns:
        if c not in rows[0]:
            raise StringsBenchError(f"{path} has no column {c!r}", hint=f"its columns: {', '.join(rows[0])}")
        if c not in RESULT_COLUMNS:
            raise StringsBenchError(f"no heading known for results column {c!r}",
                                    hint=f"known: {', '.join(RESULT_COLUMNS)}")
    bold = options.get("bold", ["0"])[-1] == "1"
    best: dict[tuple[str, str], float] = {}
    if bold:
        for c in columns:
            way = RESULT_COLUMNS[c][2]
            for r in rows:
                v = _number(r[c])
                if way is None or v is None:
                    continue
                key = (r.get("label", ""), c)
                cur = best.get(key)
                if cur is None or (v < cur if way == "min" else v > cur):
                    best[key] = v
    out = []
    for r in rows:
        line = []
        for c in columns:
            text = format_value(r[c], RESULT_COLUMNS[c][1])
            v = _number(r[c])
            if bold and v is not None and RESULT_COLUMNS[c][2] and best.get((r.get("label", ""), c)) == v:
                text = f"**{text}**"
            line.append(text)
        out.append(line)
    return markdown([RESULT_COLUMNS[c][0] for c in columns], out)


def table_compare(rows: list[dict[str, str]], options: dict, path: Path) -> str:
    values = ",".join(options.get("values", ["cer,cer_known"])).split(",")
    labels = ",".join(options.get("labels", [])).split(",") if options.get("labels") else sorted(
        {r["label"] for r in rows}, key=lambda s: (len(s), s))
    digits = int(options.get("digits", ["3"])[-1])
    methods = list(dict.fromkeys(r["method"] for r in rows))
    index = {(r["method"], r["label"], r["value"]): r for r in rows}
    if not any((m, l, v) in index for m in methods for l in labels for v in values):
        raise StringsBenchError(f"{path}: none of values={','.join(values)} at labels={','.join(labels)}")
    header = ["method", "seeds"] + [f"{COMPARE_VALUES.get(v, v)} {l}" for v in values for l in labels]
    out = []
    for m in methods:
        first = next((r for (mm, _, _), r in index.items() if mm == m), {})
        seeds, draws = first.get("seeds", ""), first.get("draws") or "1"
        line = [m, seeds if draws == "1" else f"{seeds} x {draws} draws"]
        for v in values:
            for l in labels:
                r = index.get((m, l, v))
                if r is None or _number(r["mean"]) is None:
                    line.append("n/a")
                    continue
                mean, lo, hi = (_number(r[k]) for k in ("mean", "min", "max"))
                cell = f"{mean:.{digits}f}"
                # a range over the replicates: several seeds, or several scene draws of one seed
                if lo is not None and hi is not None and (r.get("seeds", "1") not in ("", "1")
                                                          or (r.get("draws") or "1") != "1"):
                    cell += f" ({lo:.{digits}f}-{hi:.{digits}f})"
                line.append(cell)
        out.append(line)
    return markdown(header, out)


def table_compare_formatted(rows: list[dict[str, str]], options: dict, path: Path) -> str:
    from strings_bench.reports.compare import comparison_from_csv, comparison_tables

    if options.get("where"):
        raise StringsBenchError(f"{path}: kind=compare-table takes no where= (compare's tables are shown whole)")
    name = options.get("table", ["compare_cer"])[-1]
    tables = {t.name: t for t in comparison_tables(comparison_from_csv(path))}
    if name not in tables:
        raise StringsBenchError(f"{path}: compare makes no table {name!r} of this comparison",
                                hint=f"its tables: {', '.join(tables)}")
    return tables[name].markdown()


def _slug(heading: str) -> str:
    return "-".join(re.findall(r"[a-z0-9]+(?:-[a-z0-9]+)*", heading.lower()))


def markdown_section_table(text: str, section: str, path: Path) -> str:
    """The first Markdown table under the `## ` heading whose slug is `section`, as printed."""
    lines = text.splitlines()
    heads = [i for i, line in enumerate(lines) if line.startswith("## ")]
    found = [i for i in heads if _slug(lines[i][3:]) == section]
    if not found:
        raise StringsBenchError(f"{path} has no section {section!r}",
                                hint="its sections: " + ", ".join(_slug(lines[i][3:]) for i in heads))
    start = found[0] + 1
    end = next((i for i in heads if i > found[0]), len(lines))
    table, inside = [], False
    for line in lines[start:end]:
        if line.startswith("|"):
            table.append(line)
            inside = True
        elif inside:
            break
    if len(table) < 2 or not re.fullmatch(r"\|(?:-+\|)+", table[1].replace(":", "").replace(" ", "")):
        raise StringsBenchError(f"{path}: section {section!r} holds no Markdown table")
    return "\n".join(table) + "\n"


KINDS = {"csv": table_csv, "compare-table": table_compare_formatted, "results": table_results, "compare": table_compare,
         "text": table_text, "markdown": None}  # markdown: read as text (render_block)


def render_block(spec: str, page: Path) -> str:
    """The body a block with `spec` has in `page` (a Markdown table ending in a newline)."""
    data, options = parse_spec(spec)
    kind = options.get("kind", ["csv"])[-1]
    if kind not in KINDS:
        raise StringsBenchError(f"{page}: unknown table kind {kind!r}", hint=f"kinds: {', '.join(KINDS)}")
    path = (page.parent / data).resolve()
    if kind == "markdown":  # a command's Markdown output, not a CSV
        if options.get("where") or not options.get("section"):
            raise StringsBenchError(f"{page}: kind=markdown takes section=SLUG and no where= (the table as printed)")
        if not path.is_file():
            raise StringsBenchError(f"table data {path} does not exist")
        return markdown_section_table(path.read_text(encoding="utf-8"), options["section"][-1], path)
    rows = _filter(read_csv(path), options, path)
    return KINDS[kind](rows, options, path)


def blocks(text: str) -> list[Block]:
    return [Block(m["spec"], m["body"], m.start("body"), m.end("body")) for m in BLOCK_RE.finditer(text)]


def refresh_text(text: str, page: Path) -> str:
    """`text` (the content of `page`) with every generated block rewritten from its data."""
    found = blocks(text)
    if text.count(OPEN) != len(found):
        raise StringsBenchError(f"{page}: {text.count(OPEN)} table markers but {len(found)} whole blocks",
                                hint=f"every '{OPEN}...-->' line needs a '{CLOSE}' after its table")
    out, pos = [], 0
    for b in found:
        out += [text[pos:b.start], render_block(b.spec, page)]
        pos = b.end
    out.append(text[pos:])
    return "".join(out)


def refresh_page(page: Path, check: bool = False) -> bool:
    """Rewrite `page`'s generated blocks (or, with `check`, only compare). True when the page was (or would be)
    changed."""
    text = page.read_text(encoding="utf-8")
    new = refresh_text(text, page)
    if new == text:
        return False
    if not check:
        page.write_text(new, encoding="utf-8")
    return True
