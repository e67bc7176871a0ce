"""The README's gallery (media/, recorded by ``taichi-sim record --showcase``) shows the presets as
they are.

media/gallery.json says what each GIF and still was recorded from (and each still carries the
same in its PNG text); the first tests compare that with the presets and the showcase table
without recording anything, so a preset whose default integrator, step, options or tolerance
changes fails here until its entry is re-recorded (``taichi-sim record --showcase --only NAME``).
The last tests record small clips offscreen: ``fit`` frames the cloth, the CLI's bad input.
"""
import dataclasses
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from helpers import OffscreenWindows
from PIL import Image

from taichi_sim.app.record import PNG_TEXT_KEY, Clip, record
from taichi_sim.app.showcase import MANIFEST, SHOWCASE, read_manifest, stale_items
from taichi_sim.cli import main
from taichi_sim.scene import SCENES

ROOT = Path(__file__).resolve().parents[1]
MEDIA = ROOT / "media"
PROVENANCE_KEYS = ("scene", "integrators", "dt", "integrator_options", "tolerance", "params", "seed", "t", "steps")

SIZE = (160, 96)
WINDOWS = OffscreenWindows(SIZE)
runtime, window, own_windows = WINDOWS.fixtures()


def test_the_gallery_is_recorded_from_the_presets_as_they_are():
    stale = stale_items(read_manifest(MEDIA))
    assert stale == [], "re-record with `taichi-sim record --showcase --only NAME`:\n" + "\n".join(stale)


def test_every_shown_gallery_file_is_in_the_manifest_and_carries_what_it_shows():
    items = read_manifest(MEDIA)
    names = {e.name for e in SHOWCASE}
    shown = set()
    for page in [ROOT / "README.md", ROOT / "docs" / "index.md"]:
        shown |= {stem for stem in re.findall(r"\(media/([\w-]+)\.(?:gif|png)\)", page.read_text()) if stem in names}
    assert len(shown) >= 12 and shown <= set(items)
    for name, item in items.items():
        gif, png = MEDIA / item["gif"], MEDIA / item["png"]
        assert gif.stat().st_size < 2_000_000 and png.stat().st_size < 2_000_000
        with Image.open(gif) as video:
            assert video.n_frames == item["frames"] and list(video.size) == item["size"]
        with Image.open(png) as still:
            assert list(still.size) == [item["supersample"] * side for side in item["size"]]
            assert json.loads(still.text[PNG_TEXT_KEY]) == {k: item[k] for k in PROVENANCE_KEYS}, name
        # the still's frame: a fraction still_at of the clip, speed / fps simulated seconds a frame
        frame = round(item["still_at"] * (item["frames"] - 1))
        if not item["failures"]:
            assert item["t"] == pytest.approx(frame * item["speed"] / item["fps"], abs=item["dt"])
            assert item["steps"] * item["dt"] == pytest.approx(item["t"], abs=item["dt"])


@pytest.mark.parametrize("change, wanted", [
    ({"default_integrator": "symplectic_euler"}, "cloth-fold: recorded with integrators = ['vbd'], now ['symplectic_euler']"),
    ({"default_dt": 1 / 30}, "cloth-fold: recorded with dt = 0.016666666666666666, now 0.03333333333333333"),
    ({"integrator_options": {"vbd": {"iterations": 3}}},
     "cloth-fold: recorded with integrator_options = {'vbd': {}}, now {'vbd': {'iterations': 3}}"),
    ({"default_tolerance": 1e-3}, "cloth-fold: recorded with tolerance = 0.005, now 0.001"),
])
def test_a_preset_changed_without_re_recording_reads_as_stale(monkeypatch, change, wanted):
    monkeypatch.setitem(SCENES, "cloth-fold", dataclasses.replace(SCENES["cloth-fold"], **change))
    assert wanted in stale_items(read_manifest(MEDIA))


def test_a_table_entry_changed_without_re_recording_reads_as_stale():
    items = read_manifest(MEDIA)
    entries = tuple(dataclasses.replace(e, clip=dataclasses.replace(e.clip, dt=0.05)) if e.name == "simple-trail"
                    else dataclasses.replace(e, still_at=0.5) if e.name == "cloth" else e for e in SHOWCASE)
    assert stale_items(items, entries) == ["cloth: recorded with still_at = 0.75, now 0.5",
                                           "simple-trail: recorded with dt = 0.1, now 0.05"]
    # a preset entry whose clip leaves the preset's integrator is refused unless marked chosen
    entries = tuple(dataclasses.replace(e, clip=dataclasses.replace(e.clip, integrators=("rk4",)))
                    if e.name == "pendulum" else e for e in SHOWCASE)
    assert stale_items(items, entries)[0].startswith("pendulum: not chosen, yet its clip runs rk4")
    assert stale_items({k: v for k, v in items.items() if k != "garment"}) == ["garment: not recorded"]


# -- recording (offscreen) ----------------------------------------------------------------------------

def _cloth_span(path) -> float:
    """How much of an image's width or height (the larger share) the cloth spans: the
    gingham's saturated blue and orange pixels (the ground and the background are grey)."""
    rgb = np.asarray(Image.open(path).convert("RGB")).astype(int)
    rows, cols = np.nonzero(rgb.max(axis=2) - rgb.min(axis=2) > 60)
    if not len(rows):
        return 0.0
    return max((np.ptp(cols) + 1) / rgb.shape[1], (np.ptp(rows) + 1) / rgb.shape[0])


def test_fit_frames_the_folded_cloth_in_the_still(own_windows, tmp_path):
    clip = Clip(scene="cloth-fold", integrators=("vbd",), params={"nx": 8, "ny": 8}, seconds=1.5, fps=4,
                size=SIZE, fit=True)
    fitted = record(clip, tmp_path / "fit.gif", still=tmp_path / "fit.png", progress=False)
    # the cloth lies folded on the ground at the end: framed, it spans the still (the start-up
    # view frames the cloth hanging 1.1 m up and the ground: the pile spans 40 % of the width)
    assert _cloth_span(fitted.still) > 0.65, _cloth_span(fitted.still)
    # the still's time and step, in the PNG as in the result
    assert json.loads(Image.open(fitted.still).text[PNG_TEXT_KEY]) == fitted.provenance
    assert fitted.provenance["t"] == pytest.approx(1.25) and fitted.provenance["steps"] == 75  # the last frame


@pytest.mark.parametrize("args, message", [
    (["record", "--only", "cloth-fold", "--out", "x.gif"], "--only picks showcase entries"),
    (["record", "--showcase", "{tmp}", "--only", "cloth-fodl"], "no showcase entry cloth-fodl (choose from cloth,"),
    (["record", "cloth", "--side-by-side", "euler,rk4", "--fit", "--out", "{tmp}/x.gif"], "fit frames one run"),
    (["record", "--showcase", "{tmp}", "--fit"], "drop --fit"),
])
def test_record_refuses_bad_gallery_options_in_one_line(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert main([a.format(tmp=tmp_path) for a in args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert os.listdir(tmp_path) == [] and not (tmp_path / MANIFEST).exists()
