"""The documentation pictures: every picture in ``docs/img/`` is made by ``benchmarks/pictures.py``
(its table :data:`PICTURES`), every entry of that table is in the folder, and every picture that
README.md or a page under docs/ shows is in ``docs/img/``. Reads the table only: no Chromium, no run."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from testbed.sim.evaluate import REGIONS

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "img"
#: Markdown image links ``![alt](path "title")`` and HTML ``<img src="path">``
IMAGE_LINK = re.compile(r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)|<img\s[^>]*src=[\"']([^\"']+)[\"']")


def _pictures_module():
    spec = importlib.util.spec_from_file_location("docs_pictures", ROOT / "benchmarks" / "pictures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _image_links(page: Path) -> list[str]:
    text = page.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # examples in fenced code are not pictures shown
    return [a or b for a, b in IMAGE_LINK.findall(text)]


def test_the_table_and_the_folder_agree():
    table = _pictures_module().PICTURES
    folder = {p.name for p in IMG.glob("*") if p.is_file()}
    assert sorted(folder - set(table)) == [], "pictures in docs/img/ that benchmarks/pictures.py does not make"
    assert sorted(set(table) - folder) == [], "pictures benchmarks/pictures.py makes that are not in docs/img/"


def test_every_entry_says_how_it_is_made():
    for name, p in _pictures_module().PICTURES.items():
        assert name == p.name and name.endswith(".png")
        assert p.kind in ("recording", "figure"), name
        assert p.command.strip() and callable(p.make), name
        assert bool(p.source) == (p.kind == "figure"), name  # a figure says which output it copies


def test_the_script_lists_its_table_without_running_anything(capsys):
    assert _pictures_module().main(["--list"]) == 0
    out = capsys.readouterr().out
    for name in _pictures_module().PICTURES:
        assert name in out


def test_only_takes_a_name_with_or_without_its_prefix_and_suffix():
    mod = _pictures_module()
    assert {mod._name(n) for n in ("readme-dpe-vs-raim.png", "readme-dpe-vs-raim", "dpe-vs-raim")} == {
        "readme-dpe-vs-raim.png"}
    with pytest.raises(SystemExit, match="no picture 'nope'"):
        mod.main(["--only", "nope", "--out", "/nonexistent"])


def test_every_picture_shown_in_the_docs_is_in_docs_img():
    bad = []
    for page in _pages():
        for link in _image_links(page):
            if re.match(r"[a-z]+:", link):  # an absolute URL: not ours to check
                continue
            target = (page.parent / link.split("#")[0]).resolve()
            if target.parent != IMG.resolve() or not target.is_file():
                bad.append(f"{page.relative_to(ROOT)}: {link}")
    assert bad == [], "pictures shown that are not files of docs/img/"


def test_the_image_link_pattern():
    page = '![a](../img/x.png) text ![b c](img/y.png "t") <img src="z.png" width=3>\n```\n![no](q.png)\n```\n'
    assert IMAGE_LINK.findall(re.sub(r"```.*?```", "", page, flags=re.S)) == [
        ("../img/x.png", ""), ("img/y.png", ""), ("", "z.png")]


def _panel(dim: str, total: int, no_solution: int, al: float):
    from testbed.viz.stanford import hist_edges

    edges = hist_edges()
    H = np.zeros((len(edges) - 1, len(edges) - 1))
    if no_solution < total:
        H[60, 70] = total - no_solution
    counts = dict.fromkeys(REGIONS, 0) | {"normal": total - no_solution, "no_solution": no_solution}
    return (dim, H, counts, total, al), edges


def _plot_axes(fig) -> list:
    return [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]


def test_a_monitor_without_hpl_gets_its_v_diagram_alone():
    """The DPE bounds the vertical only: no empty H panel (readme-dpe-vs-raim.png), the title says why."""
    from testbed.viz.stanford import stanford_figure

    (h, edges), (v, _) = _panel("H", 100, 100, 40.0), _panel("V", 100, 3, 20.0)
    axes = _plot_axes(stanford_figure("dpe", [h, v], edges))
    assert len(axes) == 1
    assert axes[0].get_title().startswith("dpe: V Stanford diagram") and "gives no HPL" in axes[0].get_title()
    both = _plot_axes(stanford_figure("gps_raim", [_panel("H", 100, 3, 40.0)[0], v], edges))
    assert [ax.get_title().split("\n")[0] for ax in both] == ["gps_raim: H Stanford diagram (HAL 40 m)",
                                                            "gps_raim: V Stanford diagram (VAL 20 m)"]


def test_a_monitor_with_no_pl_at_all_keeps_both_panels_without_limit_lines():
    from testbed.viz.stanford import stanford_figure

    (h, edges), (v, _) = _panel("H", 50, 50, 40.0), _panel("V", 50, 50, 20.0)
    axes = _plot_axes(stanford_figure("m", [h, v], edges))
    assert len(axes) == 2
    for ax in axes:
        assert not ax.lines  # no alert-limit or y = x line under the message
        assert any("gives no" in t.get_text() for t in ax.texts)


@pytest.mark.parametrize("camera, map_", [(True, True), (False, True), (True, False)])
def test_the_layout_leaves_out_the_camera_and_map_views_when_asked(tmp_path, camera, map_):
    """A flight without a camera gets no empty camera view; the screenshots leave out the map (its tiles
    come from the internet)."""
    import rerun as rr

    from testbed.viz import readback
    from testbed.viz.blueprint import default_blueprint

    path = tmp_path / "layout.rrd"
    rec = rr.RecordingStream("testbed", recording_id="layout", send_properties=False)
    rec.set_sinks(rr.FileSink(str(path)))
    rec.send_blueprint(default_blueprint(["gps_raim"], alert_limits=(40.0, 20.0),
                                         camera_resolution=(640, 480) if camera else None, map_view=map_),
                       make_active=True, make_default=True)
    rec.flush()
    rec.disconnect()
    origins = {v["origin"] for v in readback.views(path)}
    assert {"/world", "/world/follow", "/alerts"} <= origins
    assert ("/world/camera" in origins) == camera
    assert ("/map" in origins) == map_
