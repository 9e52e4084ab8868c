"""``wearable-gaze markers``: printable, exact-scale ArUco marker sheets (PDF or PNG) and the
marker-map template to fill in with where each marker is put (docs/session.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2

from calibration.camera import aruco_dictionary

from ...errors import UserError, check_output
from ...formats.atomic import atomic_path
from ...formats.markermap import marker_map_template, write_marker_map

log = logging.getLogger(__name__)

MAX_IDS = 10000


def parse_ids(text: str) -> list[int]:
    """'0-11', '3,5,7-9' -> ids (each once, in the order given).

    Raises:
        UserError: not ids, a range written backwards (5-3), a negative id, or more than
            ``MAX_IDS`` ids.
    """
    ids = []
    safe = ascii(text)
    for part in text.split(","):
        try:
            if "-" in part.strip()[1:]:
                a, b = (int(v) for v in part.split("-"))
                if b < a:
                    raise UserError(f"--ids {safe}: the range {a}-{b} runs backwards; write {b}-{a}")
                if b - a >= MAX_IDS:
                    raise UserError(f"--ids {safe}: more than {MAX_IDS} ids; print fewer at a time")
                ids += list(range(a, b + 1))
            else:
                ids.append(int(part))
        except ValueError:
            raise UserError(f"--ids {safe}: give ids like 0-11 or 3,5,7-9") from None
    neg = [i for i in ids if i < 0]
    if neg:
        raise UserError(f"--ids {safe}: id {neg[0]} is negative; give ids of 0 or more")
    if not ids:
        raise UserError(f"--ids {safe}: no ids; give ids like 0-11 or 3,5,7-9")
    if len(ids) > MAX_IDS:
        raise UserError(f"--ids {safe}: more than {MAX_IDS} ids; print fewer at a time")
    return list(dict.fromkeys(ids))



PAGE_MM = {"a4": (210.0, 297.0), "letter": (215.9, 279.4), "a3": (297.0, 420.0)}
MAX_DPI = 1200          # an A3 page at 1200 dpi is 14000 x 19800 pixels; more exhausts memory


@dataclass(frozen=True)
class _Layout:
    """Where the markers go on a page (mm from the top-left corner)."""

    page: tuple            # (width, height)
    margin: float
    size: float            # the marker's black square
    module: float          # one bit of the marker: the white quiet zone around it
    cell: float            # the pitch of the grid
    cols: int
    rows: int


def write_marker_sheets(dictionary: str, ids, size_mm: float, out, page: str = "a4", dpi: int = 300,
                        margin_mm: float = 12.0) -> list:
    """Exact-scale marker sheets: each marker with a white quiet zone of one module, a dashed
    cut line, its id, dictionary and size printed under it. PDF (vector page, raster markers at
    ``dpi``) or PNG at ``dpi``. Also writes ``<out>_map_template.json`` to fill in. Returns
    the paths written."""
    dic = _checked_dictionary(dictionary, ids, size_mm, dpi)
    out = Path(out)
    if out.suffix.lower() not in (".pdf", ".png"):
        raise UserError(f"-o {out}: write .pdf or .png")
    template = out.with_name(out.stem + "_map_template.json")
    check_output(out, (), "-o")
    check_output(template, (), "-o (its map template)")
    lay = _layout(dic, size_mm, page, margin_mm)
    per_page = lay.cols * lay.rows
    pages = [ids[k:k + per_page] for k in range(0, len(ids), per_page)]
    written = _write_pages(out, pages, dic, dictionary, lay, dpi)
    write_marker_map(template, marker_map_template(dictionary, size_mm, ids))
    log.info("%d marker(s) on %d page(s): %s", len(ids), len(pages), ", ".join(map(str, written)))
    return [*written, template]


def _checked_dictionary(dictionary: str, ids, size_mm: float, dpi: int):
    """The ArUco dictionary, once ids, size and resolution are checked against it."""
    try:
        dic = aruco_dictionary(dictionary)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    n_ids = dic.bytesList.shape[0]
    bad = [i for i in ids if not 0 <= i < n_ids]
    if bad:
        raise UserError(f"--ids: ids {bad[:5]} are not in {dictionary}; use ids 0-{n_ids - 1} or a larger --dict")
    if not 5 <= size_mm <= 1000:
        raise UserError(f"--size-mm {size_mm:g}: give the marker side in millimetres, 5-1000")
    if not 50 <= dpi <= MAX_DPI:
        raise UserError(f"--dpi {dpi}: give a resolution of 50-{MAX_DPI} dots per inch (default 300)")
    if not ids:
        raise UserError("--ids: no ids to print; give ids like 0-11 or 3,5,7-9")
    return dic


def _layout(dic, size_mm: float, page: str, margin_mm: float) -> _Layout:
    pw, ph = PAGE_MM[page]
    module = size_mm / (dic.markerSize + 2)
    cell = size_mm + 2 * module + 12.0                      # quiet zone both sides + label room
    if size_mm + 2 * module > min(pw, ph) - 2 * margin_mm:
        raise UserError(f"a {size_mm:g} mm marker does not fit on a {page} page with margins; use --page a3")
    return _Layout((pw, ph), margin_mm, size_mm, module, cell, max(int((pw - 2 * margin_mm) // cell), 1),
                   max(int((ph - 2 * margin_mm) // cell), 1))


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _write_pages(out: Path, pages, dic, dictionary: str, lay: _Layout, dpi: int) -> list:
    """One PDF of all pages, or one PNG per page (``out``, else ``<out>_<n>.png``)."""
    plt = _plt()
    written = []
    if out.suffix.lower() == ".pdf":
        from matplotlib.backends.backend_pdf import PdfPages
        with atomic_path(out) as tmp, PdfPages(tmp) as pdf:
            for p in pages:
                fig = _draw_page(p, dic, dictionary, lay, dpi)
                pdf.savefig(fig)
                plt.close(fig)
        written.append(out)
    else:
        for n, p in enumerate(pages):
            path = out if len(pages) == 1 else out.with_name(f"{out.stem}_{n + 1}{out.suffix}")
            fig = _draw_page(p, dic, dictionary, lay, dpi)
            with atomic_path(path) as tmp:
                fig.savefig(tmp, dpi=dpi)
            plt.close(fig)
            written.append(path)
    return written


def _draw_page(page_ids, dic, dictionary: str, lay: _Layout, dpi: int):
    """A matplotlib figure of one page, 1 unit = 1 mm."""
    plt = _plt()
    (pw, ph), size_mm, module = lay.page, lay.size, lay.module
    fig = plt.figure(figsize=(pw / 25.4, ph / 25.4), dpi=dpi)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, pw)
    ax.set_ylim(ph, 0)
    ax.axis("off")
    px = max(int(round(size_mm / 25.4 * dpi)), 8 * (dic.markerSize + 2))
    for k, mid in enumerate(page_ids):
        r, c = divmod(k, lay.cols)
        x0 = lay.margin + c * lay.cell + module
        y0 = lay.margin + r * lay.cell + module
        img = cv2.aruco.generateImageMarker(dic, int(mid), px, borderBits=1)
        ax.imshow(img, cmap="gray", vmin=0, vmax=255, extent=(x0, x0 + size_mm, y0 + size_mm, y0),
                  interpolation="nearest")
        ax.add_patch(plt.Rectangle((x0 - module, y0 - module), size_mm + 2 * module, size_mm + 2 * module,
                                   fill=False, ls=(0, (4, 4)), lw=0.4, ec="0.5"))
        ax.text(x0, y0 + size_mm + module + 3.5, f"id {mid}  {dictionary}  {size_mm:g} mm (black square)",
                fontsize=6, va="top")
    ax.text(lay.margin, ph - 5, f"wearable-gaze markers: print at 100 % (no scaling); check the {size_mm:g} mm side "
            "with a ruler", fontsize=6)
    return fig
