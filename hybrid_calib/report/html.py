"""The HTML of the report pages: one self-contained file (inline CSS, images as data URIs, a few
lines of vanilla JavaScript to sort tables; nothing fetched from anywhere)."""

from __future__ import annotations

import base64
import glob
import html
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from hybrid_calib.atomic import fit_name, out_dir_lock
from hybrid_calib.config import save_text_atomic
from hybrid_calib.errors import DataError, check_out_not_in_dataset, page_target

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;margin:1.5em auto;
padding:0 1em;color:#222;line-height:1.4;overflow-wrap:anywhere}
h1{font-size:1.5em;margin-bottom:.2em}
h2{font-size:1.15em;border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
.meta{color:#666;font-size:.85em}
.verdict{border-radius:8px;padding:.8em 1.1em;margin:1em 0;border:2px solid}
.verdict .word{font-size:1.6em;font-weight:700;text-transform:uppercase;letter-spacing:.03em}
.v-ok{background:#eaf7ea;border-color:#3a9a3a} .v-bad{background:#fdeaea;border-color:#c63b3b}
.v-unk{background:#fff6e0;border-color:#d69a1a}
table{border-collapse:collapse;margin:.4em 0;font-size:.92em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f3f3f3} td.l,th.l{text-align:left}
table.sortable th{cursor:pointer} table.sortable th:after{content:" \\2195";color:#aaa}
img{max-width:100%;border:1px solid #ddd;margin:.3em 0} .note{color:#8a5a00;background:#fff8e8;padding:.3em .6em}
code{background:#f4f4f4;padding:0 .2em}
"""

SORT_JS = """
document.querySelectorAll('table.sortable').forEach(function(t){
  t.querySelectorAll('th').forEach(function(th,i){th.addEventListener('click',function(){
    var body=t.tBodies[0],rows=Array.prototype.slice.call(body.rows),asc=th.dataset.asc!=='1';
    th.dataset.asc=asc?'1':'0';
    rows.sort(function(a,b){var x=a.cells[i].dataset.sort||a.cells[i].textContent,
      y=b.cells[i].dataset.sort||b.cells[i].textContent,nx=parseFloat(x),ny=parseFloat(y);
      var c=(!isNaN(nx)&&!isNaN(ny))?nx-ny:x.localeCompare(y);return asc?c:-c;});
    rows.forEach(function(r){body.appendChild(r);});});});});
"""


def esc(x) -> str:
    return html.escape(str(x), quote=True)


def img_tag(png: Path, alt: str) -> str:
    """An ``<img>`` with the PNG embedded as a data URI."""
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    return f'<img alt="{esc(alt)}" src="data:image/png;base64,{data}">'


def num(value: float, fmt: str, key: str = "") -> str:
    """A table cell with the shown number and the exact value in ``data-value`` (tests compare it)."""
    k = f' data-key="{esc(key)}"' if key else ""
    v = float(value)  # beyond 1e9 in scientific notation (probe 112: a 300-digit figure widened the table)
    return f'<td{k} data-value="{v!r}">{format(v, fmt if abs(v) < 1e9 else ".3g")}</td>'


def verdict_class(word: str) -> str:
    return {"within tolerance": "v-ok", "recalibrate": "v-bad"}.get(word, "v-unk")


SOURCE_META = "hybrid-calib-source"  # a page's <meta>: what it was written from (report.vehicle.page_key)


def page(title: str, body: str, source: str = "") -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            + (f"<meta name=\"{SOURCE_META}\" content=\"{esc(source)}\">" if source else "") +
            f"<title>{esc(title)}</title><style>{CSS}</style></head>\n<body>\n{body}\n"
            f"<script>{SORT_JS}</script>\n</body></html>\n")


def is_html(path: Path) -> bool:
    """Whether the file at ``path`` may be replaced by a page: an HTML page by its first bytes (after a byte-order
    mark, white space and comments: a browser's "saved from" line; probe 69 refused those), or an empty file;
    False for what is not a regular file (a named pipe there hung the report, opened to read: probe 66)."""
    if not Path(path).is_file():
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    head = head.removeprefix(b"\xef\xbb\xbf").lstrip().lower()
    while head.startswith(b"<!--") and b"-->" in head:
        head = head[head.index(b"-->") + 3:].lstrip()
    return not head or head.startswith((b"<!doctype html", b"<html"))


def write_page(path: Path, title: str, body: str, source: str = "") -> Path:
    """Write the page atomically; returns its path. ``source``: what it was written from (``SOURCE_META``).
    ``DataError`` where ``path`` holds a file that is not an HTML page (a user's file is never replaced). A symbolic
    link is followed: the page it points to is written (probe 69: the link was replaced by a file, its page kept)."""
    path = page_target(path, "out")  # a link's target, checked as the page itself (probe 70)
    check_out_not_in_dataset(path.parent, "out")
    if path.exists() and not path.is_dir() and not is_html(path):
        raise DataError(f"{path} exists and is not an HTML page, so it is not replaced by the report; move it away, "
                        "or write the page elsewhere")
    return save_text_atomic(path, page(title, body, source))


def written_from(path: Path, source: str) -> bool:
    """Whether the page at ``path`` was written from ``source`` (its ``SOURCE_META``): a rerun keeps it."""
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False
    # and whole: a page cut short (probe 59: 5000 bytes, ending mid-table) is written again
    return f"<meta name=\"{SOURCE_META}\" content=\"{esc(source)}\">" in text[:4096] and \
        text.rstrip().endswith("</html>")


@contextmanager
def page_lock(page: Path, command: str, reentrant: bool = True) -> Iterator[None]:
    """Hold the lock of one page (``.<page name>.lock`` beside it) while ``command`` writes it: a second writer of
    that page gets ``OutDirBusy`` naming the first (probe 60: two report runs both said "wrote" and one page was
    lost). ``reentrant`` (the library's ``write_report`` / ``write_fleet_page``): a lock this thread holds already is
    the report command's around them, and they go on under it, so a library call is kept apart from another writer
    as the command is (it removed the other writer's figures folder); the command itself takes it as the outermost."""
    page = Path(page)
    with out_dir_lock(page.parent, command, name=fit_name(f".{page.name}.lock"), what=f"the page {page}",
                      reentrant=reentrant):
        yield


@contextmanager
def figures_folder(page: Path) -> Iterator[Path]:
    """A temporary folder beside ``page`` for its figures (they are embedded in it), removed at the end, and the ones
    a killed run left for this page removed first (the page's lock keeps two runs of it apart). In the system's
    temporary folder a killed report left its figures for ever, and a figure that could not be written was named by a
    path the user never chose (probe 111)."""
    stem = fit_name(f".{page.name}.figures-", 200)
    for old in page.parent.glob(f"{glob.escape(stem)}*"):
        shutil.rmtree(old, ignore_errors=True)
    page.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=stem, dir=page.parent))
    try:
        yield tmp
    except OSError as e:
        if e.filename is None or not Path(e.filename).resolve().is_relative_to(tmp.resolve()):
            raise
        raise OSError(e.errno, f"the figures of {page} cannot be written ({e.strerror or e})", str(page)) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
