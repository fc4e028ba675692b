"""A legible scene (issue 20.3-20.4): compact track labels, the colour key drawn from the scene's palette, a
sensor car and boundary layers in styles no other entity uses, and the per-track diagnostics one plot per
quantity (recording and blueprint read back)."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from rerun.chunk import RrdReader

from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.recording import diagnostics as dg, palette as pal, slots
from roadtrack.testbed.recording.legend import BACKGROUND, ENTRIES, ROW_PX, legend_image
from roadtrack.testbed.recording.recorder import Recorder
from roadtrack.testbed.recording.scene import LAYER_MIN_HALF_M, track_label
from roadtrack.testbed.scenario.spec import load_scenario

SOLID = 3  # rerun 0.41 FillMode.Solid


def test_track_labels_are_compact_and_name_only_a_regime_that_says_something_is_wrong():
    assert track_label(3, "tracking") == "T3"
    assert track_label(3, "unknown") == "T3"  # the KS window is not full yet: every new track (issue 34.4)
    assert track_label(12, "track-lost") == "T12 track-lost"
    assert track_label(4, "ambiguous") == "T4 ambiguous"


@pytest.mark.parametrize("name, group", [
    ("score", "score"), ("nis", "nis"), ("gate_volume", "gate"), ("position_std", "position_std"),
    ("w0", "association"), ("n_gated", "association"), ("pd", "association"), ("mu_0", "modes"),
    ("psi_z_1", "layer_z"), ("ct.psi_z_0", "layer_z"), ("cv.psi_y_1", "layer_y"), ("psi_v_0", "layer_y"),
    ("ct.chatter_1", "chatter"), ("chatter_0", "chatter"), ("cv.regime_y", "svsf_regime"),
    ("ks_D_T", "ks"), ("ks_regime", "ks"), ("my_quantity", "other")])
def test_each_diagnostic_goes_to_the_plot_of_its_quantity(name, group):
    assert dg.group_of(name) == group
    assert dg.series_path(name) == f"diagnostics/{group}/{name}"


def test_every_group_title_names_its_units_or_scale():
    for key, title in dg.titles():
        if key not in ("other", "modes", "svsf_regime", "association", "ks", "score", "nis", "slots"):
            assert "[" in title, title  # a quantity with a unit says it


def test_the_legend_is_drawn_in_the_scenes_colours():
    img = legend_image()
    assert img.dtype == np.uint8 and img.shape == (ROW_PX * (len(ENTRIES) + 1), img.shape[1], 3)
    flat = img.reshape(-1, 3)

    def has(c):
        return bool(np.all(flat == np.array(c, np.uint8), axis=1).any())

    assert has(pal.EGO) and has(pal.DETECTION) and has(pal.CLUTTER) and has(pal.MERGED)
    a = pal.LAYER[3] / 255  # translucent: drawn blended on the background, as the viewer shows it
    assert has([round(a * v + (1 - a) * b) for v, b in zip(pal.LAYER[:3], BACKGROUND)])
    # one swatch per row: each row has non-background pixels left of the label
    for row in range(1, len(ENTRIES) + 1):
        block = img[row * ROW_PX: (row + 1) * ROW_PX, :60]
        assert (block != np.array(BACKGROUND, np.uint8)).any(axis=2).sum() > 20, ENTRIES[row - 1][0]


def test_only_the_sensor_car_is_solid_and_only_layers_are_translucent():
    assert len(pal.LAYER) == 4 and pal.LAYER[3] < 128 and len(pal.EGO) == 3
    others = [pal.DETECTION, pal.CLUTTER, pal.MERGED, pal.SPLIT, pal.COMPLETED, pal.REJECTED, pal.ROAD_AS_OBJECT,
              pal.OBJECT_AS_ROAD, *map(tuple, pal.CLUSTERS)]
    assert tuple(pal.EGO) not in {tuple(int(v) for v in c) for c in others}


def _rows(rrd) -> dict[str, list]:
    out: dict[str, list] = {}
    for chunk in RrdReader(str(rrd)).stream():
        out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out


def test_recording_has_the_legend_diagnostics_per_quantity_and_compact_labels(tmp_path):
    """4 s of cut_in_out with imm-jpda-gvbl-svsf: the legend image is static; each diagnostic name has one series
    per slot, diagnostics/<its group>/<name>/<k>, named "<name>, slot <k>" and in the slot's colour, whatever
    the number of tracks; the confirmed tracks' labels carry no "tracking" nor "warming up" (issue 34.4), and
    their points have their slot's colour; the ego box is solid; the SVSF layers are drawn at least 0.6 m wide,
    else at true size; the count plots draw detections green and clutter red, as the scene; the blueprint has one time-series
    tab per group."""
    scn = load_scenario("cut_in_out", {"duration_s": 4.0, "record.lidar_every": 0})
    run_scenario(scn, out_dir=tmp_path, record=True, tracker="imm-jpda-gvbl-svsf")
    rows = _rows(tmp_path / "run.rrd")
    (legend,) = rows["/legend"]
    assert "frame" not in legend.schema.names  # static
    diag = [p for p in rows if p.startswith("/diagnostics/")]
    names = set(pd.read_parquet(tmp_path / "diagnostics.parquet").name.unique())
    assert {p.split("/")[2] for p in diag} >= {"score", "nis", "gate", "modes", "layer_z", "layer_y", "chatter",
                                              "slots"}
    slot_at: dict[int, dict[int, float]] = {}  # frame -> slot -> track id
    for p in diag:
        if p.startswith("/" + dg.SLOT_IDS + "/"):
            k = int(p.rsplit("/", 1)[1])
            for rb in rows[p]:
                if "Scalars:scalars" in rb.schema.names:
                    for f, v in zip(rb.column("frame").to_pylist(), rb.column("Scalars:scalars").to_pylist()):
                        slot_at.setdefault(f, {})[k] = v[0]
    n = 1 + max(k for held in slot_at.values() for k in held)
    assert n >= 2 and {int(v) for held in slot_at.values() for v in held.values() if np.isfinite(v)} <= set(
        pd.read_parquet(tmp_path / "tracks.parquet").track_id)
    assert len(diag) <= (len(names) + 1) * n  # per name and slot, not per track
    for p in diag:
        _, _, group, name, k = p.split("/")
        if group != "slots":
            assert dg.group_of(name) == group and name in names
        (style,) = [rb for rb in rows[p] if "SeriesLines:names" in rb.schema.names]
        assert style.column("SeriesLines:names").to_pylist()[-1][0].endswith(f", slot {k}"), p
        assert style.column("SeriesLines:colors").to_pylist()[-1] == [
            int.from_bytes(bytes([*slots.colours([int(k)])[0], 255]), "big")]
    labels = [v for rb in rows["/world/tracks/confirmed"] if "Points3D:labels" in rb.schema.names
              for row in rb.column("Points3D:labels").to_pylist() if row for v in row]
    assert labels and not any("tracking" in v or "unknown" in v for v in labels)
    assert not any("warming up" in v for v in labels) and any(v.startswith("T") and " " not in v for v in labels)
    checked = 0
    for rb in rows["/world/tracks/confirmed"]:
        if "Points3D:colors" not in rb.schema.names:
            continue
        for f, ids, cols in zip(rb.column("frame").to_pylist(), rb.column("Points3D:class_ids").to_pylist(),
                                rb.column("Points3D:colors").to_pylist()):
            for tid, col in zip(ids or [], cols or []):
                (k,) = [k for k, v in slot_at[f].items() if v == tid]  # the slot the track holds then
                assert col == int.from_bytes(bytes([*pal.SLOTS[k % len(pal.SLOTS)], 255]), "big")
                checked += 1
    assert checked > 20
    ego = rows["/world/truth/ego"][0]
    assert ego.column("Boxes3D:fill_mode").to_pylist()[0] == [SOLID]  # FillMode.Solid
    layers = [rb for rb in rows["/world/tracks/layers"] if "Boxes3D:fill_mode" in rb.schema.names]
    assert layers and layers[0].column("Boxes3D:fill_mode").to_pylist()[0] == [SOLID]
    half = np.array([h for rb in rows["/world/tracks/layers"] if "Boxes3D:half_sizes" in rb.schema.names
                     for row in rb.column("Boxes3D:half_sizes").to_pylist() if row for h in row])[:, :2]
    assert half.min() >= LAYER_MIN_HALF_M - 1e-6  # cm-wide layers drawn visible (issue 34.4) ...
    assert (half > LAYER_MIN_HALF_M + 0.1).any()  # ... and wider ones at their true size
    for name, colour in (("detections", pal.DETECTION), ("clutter_detections", pal.CLUTTER)):
        (style,) = [rb for rb in rows[f"/metrics/{name}"] if "SeriesLines:colors" in rb.schema.names]
        assert style.column("SeriesLines:colors").to_pylist()[0] == [int.from_bytes(bytes([*colour, 255]), "big")]


def test_blueprint_has_one_diagnostics_tab_per_quantity_and_the_legend(tmp_path):
    rec = Recorder(tmp_path / "run.rrd", "blueprint", rate_hz=10.0)
    rec.close()
    reader = RrdReader(str(tmp_path / "run.rrd"))
    (store,) = reader.blueprints()
    views: dict[str, str] = {}
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        if "ViewBlueprint:display_name" in rb.schema.names and "ViewBlueprint:space_origin" in rb.schema.names:
            views[rb.column("ViewBlueprint:display_name").to_pylist()[-1][0]] = \
                rb.column("ViewBlueprint:space_origin").to_pylist()[-1][0]
    for key, title in dg.titles():
        assert views.get(title) == f"/diagnostics/{key}", (title, views.get(title))
    assert views.get("legend") == "/legend"


def test_the_legend_grows_only_by_what_a_run_draws():
    from roadtrack.testbed.recording.legend import EXTRAS, entries

    assert entries() == ENTRIES  # a run without a further sensor or track boxes: the legend as before
    both = entries(("boxes", "sensors"))
    assert len(both) == len(ENTRIES) + 2
    for name, (after, row) in EXTRAS.items():
        assert both[[e[0] for e in both].index(after) + 1] == row
    assert legend_image(("sensors",)).shape[0] == ROW_PX * (len(ENTRIES) + 2)
