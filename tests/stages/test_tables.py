"""Numbers for engineers (stages/tables.py): the formulas on hand-made arrays, the files and the
report, and the illuminance under a small lamp against the inverse-square + cosine law and the
exact form factor (the scene and its render are in conftest.py)."""

from __future__ import annotations

import csv
import json
import math
import os
import re

import numpy as np
import pytest

from radiosity.core.exact import polygon_form_factor
from radiosity.runtime.store import RunStore
from radiosity.stages import tables as T

Y = np.array([0.2126, 0.7152, 0.0722])


class _Bundle:
    """The fields light_tables reads, without the split trees of a real Partition."""

    def __init__(self, n, **kw):
        self.n = n
        self.__dict__.update(kw)

    def __len__(self):
        return self.n


def _tiny():
    """Two originals: 0 (two-sided, grey, 2 sub-elements), 1 (one-sided, rho 0 in blue, 1
    emitting sub-element)."""
    el = _Bundle(2, two_sided=np.array([True, False]),
                 reflectance=np.array([[[0.5, 0.5, 0.5], [0.2, 0.2, 0.2]],
                                       [[0.8, 0.4, 0.0], [0.0, 0.0, 0.0]]]),
                 emission=np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
                                    [[2.0, 2.0, 2.0], [0.0, 0.0, 0.0]]]),
                 material=np.array([0, 1]), material_names=("grey", "lamp, blue-less"),
                 source=np.array([0, 0]), sources=("/x/room.obj",), face=np.array([4, 7]),
                 area=np.array([3.0, 1.0]))
    part = _Bundle(3, orig=np.array([0, 0, 1]), area=np.array([1.0, 2.0, 1.0]),
                   center=np.array([[0.0, 0, 0], [1, 0, 0], [5, 5, 5]]),
                   normal=np.array([[0.0, 1, 0], [0, 1, 0], [0, -1, 0]]))
    L = np.zeros((3, 2, 3))
    L[0] = [[0.3, 0.2, 0.1], [0.04, 0.04, 0.04]]
    L[1] = [[0.6, 0.4, 0.2], [0.02, 0.02, 0.02]]
    L[2, 0] = [2.4, 2.2, 2.0]
    L[2, 1] = 9.0  # a solver's garbage on a one-sided back: never reported
    return part, el, L


def test_light_tables_formulas_by_hand():
    part, el, L = _tiny()
    t = T.light_tables(part, el, L)
    e = t.elements
    # fronts of all three, then the backs of the two-sided ones
    assert e["element"].tolist() == [0, 1, 2, 0, 1]
    assert e["side"].tolist() == ["front"] * 3 + ["back"] * 2
    assert e["material"].tolist() == ["grey", "grey", "lamp, blue-less", "grey", "grey"]
    np.testing.assert_array_equal(e["normal_y"], [1, 1, -1, -1, -1])
    np.testing.assert_allclose(e["radiance_y"][0], 0.3 * Y[0] + 0.2 * Y[1] + 0.1 * Y[2])
    np.testing.assert_allclose(e["luminance"], 683.0 * e["radiance_y"])
    np.testing.assert_allclose(e["exitance_g"], math.pi * np.array([0.2, 0.4, 2.2, 0.04, 0.02]))
    # E = pi (L - Le) / rho, channel by channel; NaN where rho = 0
    np.testing.assert_allclose(e["irradiance_r"],
                               math.pi * np.array([0.6, 1.2, 0.4 / 0.8, 0.2, 0.1]))
    assert np.isnan(e["irradiance_b"][2]) and np.isfinite(e["irradiance_g"][2])
    np.testing.assert_allclose(e["irradiance_g"][2], math.pi * 0.2 / 0.4)
    assert np.isnan(e["illuminance"][2])  # one undefined channel: no luminous quantity
    e0 = math.pi * Y @ [0.6, 0.4, 0.2]  # W/m^2 of Y on sub-element 0; twice that on 1
    np.testing.assert_allclose(e["illuminance"][:2], 683.0 * np.array([e0, 2 * e0]))
    # surfaces: area-weighted over the sub-elements, min / max / uniformity
    s = t.surfaces
    assert s["surface"].tolist() == [0, 0, 1] and s["side"].tolist() == ["front", "back", "front"]
    assert s["source"].tolist() == ["room.obj"] * 3 and s["face"].tolist() == [5, 5, 8]
    np.testing.assert_allclose(s["area"], [3.0, 3.0, 1.0])
    np.testing.assert_allclose(s["radiance_r"][0], (0.3 * 1 + 0.6 * 2) / 3)
    np.testing.assert_allclose(s["illuminance"][0], 683 * (e0 + 2 * 2 * e0) / 3)
    np.testing.assert_allclose(s["illuminance_min"][0], 683 * e0)
    np.testing.assert_allclose(s["illuminance_max"][0], 683 * 2 * e0)
    np.testing.assert_allclose(s["uniformity"][0], 1 / (5 / 3))
    assert np.isnan(s["illuminance"][2]) and np.isnan(s["uniformity"][2])
    m = t.materials
    assert m["material"].tolist() == ["grey", "grey", "lamp, blue-less"]
    assert m["surfaces"].tolist() == [1, 1, 1] and m["sub_elements"].tolist() == [2, 2, 1]
    # another efficacy (Radiance's 179 lm/W) scales every luminous column, nothing else
    t179 = T.light_tables(part, el, L, efficacy=179.0)
    np.testing.assert_allclose(t179.elements["luminance"], e["luminance"] * 179 / 683)
    np.testing.assert_array_equal(t179.elements["radiance_y"], e["radiance_y"])
    assert "179 lm per W" in t179.conversion
    # a structured array; and each table is what pandas.DataFrame(table) takes as it is (the
    # docs' way to a DataFrame): equal-length 1-D numpy columns, none of them object arrays
    r = t.records("surfaces")
    assert r.shape == (3,) and r["material"][2] == "lamp, blue-less"
    np.testing.assert_array_equal(r["illuminance_max"], s["illuminance_max"])
    for name in T.TABLES:
        cols = t.table(name).values()
        assert all(isinstance(c, np.ndarray) and c.ndim == 1 and c.dtype.kind in "biufU"
                   for c in cols), name
        assert len({len(c) for c in cols}) == 1, name
    with pytest.raises(KeyError, match="elements, surfaces, materials"):
        t.table("pixels")
    with pytest.raises(ValueError, match="shape"):
        T.light_tables(part, el, L[:2])



def _documented_columns() -> dict:
    """The columns docs/src/how-to/exports.md lists per file, `x_r/g/b` and `x_x/y/z` spelled
    out."""
    from helpers import ROOT

    page = open(os.path.join(ROOT, "docs", "src", "how-to", "exports.md"), encoding="utf-8").read()
    out = {}
    for name, cols in re.findall(r"^\| `(\w+)\.csv` \|[^|]*\| (.*) \|$", page, re.M):
        out[name] = []
        for col in re.findall(r"`([^`]+)`", cols):
            stem, _, alts = col.rpartition("_")
            out[name] += [f"{stem}_{a}" for a in alts.split("/")] if "/" in alts else [col]
    return out


def test_the_exports_page_lists_the_columns_of_each_file():
    """What the page says each CSV file holds is what it holds, column by column, in order."""
    t = T.light_tables(*_tiny())
    assert _documented_columns() == {name: list(t.table(name)) for name in T.TABLES}

def test_csv_round_trip_quotes_names(tmp_path):
    part, el, L = _tiny()
    t = T.light_tables(part, el, L)
    fig = T.write_light_tables(str(tmp_path), t)
    assert fig.files[:3] == ["elements.csv", "surfaces.csv", "materials.csv"]
    with open(tmp_path / "elements.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(t.elements)
    assert len(rows) == 1 + 5
    col = rows[0].index("material")
    assert rows[3][col] == "lamp, blue-less"  # quoted: the comma stays in the name
    ill = rows[0].index("illuminance")
    assert rows[3][ill] == "nan"
    got = np.array([float(r[ill]) for r in rows[1:]])
    np.testing.assert_allclose(got, t.elements["illuminance"], rtol=1e-6)
    report = json.load(open(tmp_path / "report.json"))["light"]
    assert report["efficacy_lm_per_w"] == 683.0 and report["luma"] == Y.tolist()
    lamp = report["materials"][2]
    assert lamp["material"] == "lamp, blue-less" and lamp["illuminance"] is None
    rows = T.summary_rows(report)
    assert len(rows) == 3 and "n/a (black)" in rows[2][1] and "lx" in rows[0][1]
    assert rows[1][0] == "light: grey (back)"
    many = {"materials": report["materials"] * 5}
    assert len(T.summary_rows(many)) == 1  # long lists only say where the numbers are


def _nearest(tab, x, z):
    fl = np.flatnonzero(tab["material"] == "floor")
    d = (tab["center_x"][fl] - x) ** 2 + (tab["center_z"][fl] - z) ** 2
    return fl[np.argmin(d)]


@pytest.mark.parametrize("method", ["pairs", "hierarchical"])
def test_illuminance_under_a_small_lamp(lamp_render, lamp, method):
    """Floor illuminance against the inverse-square + cosine law at the element's centre
    (E = Le A cos cos / d^2) and against the exact form factor from the element to the lamp
    (pi Le F averaged over the element), within 1 %, under the lamp and off axis, and over
    the whole floor against the law; with either transport method."""
    lamp_run = lamp_render(method)
    rs = RunStore(lamp_run)
    part = rs.load_partition()
    t = T.read_light_tables(lamp_run)
    e = t.elements
    le = np.asarray(lamp.le)
    area = lamp.side ** 2
    poly = lamp.polygon
    worst_law = worst_exact = 0.0
    for x, z in [(0.0, 0.0), (0.2, 0.05), (0.45, -0.3), (-0.7, 0.4), (0.85, 0.85)]:
        i = _nearest(e, x, z)
        c = np.array([e["center_x"][i], e["center_y"][i], e["center_z"][i]])
        d2 = float(np.sum((c - poly.mean(0)) ** 2))
        cos = lamp.height / math.sqrt(d2)  # at the lamp and at the floor: parallel planes
        law = le * area * cos * cos / d2
        sub = int(e["element"][i])
        F = polygon_form_factor(part.verts[sub, :part.nverts[sub]], poly, two_sided=False)
        exact = math.pi * le * F
        got = np.array([e[f"irradiance_{k}"][i] for k in "rgb"])
        np.testing.assert_allclose(got, law, rtol=0.01)
        np.testing.assert_allclose(got, exact, rtol=0.01)
        np.testing.assert_allclose(e["illuminance"][i], 683.0 * Y @ law, rtol=0.01)
        # the radiance the image shows: rho E / pi
        np.testing.assert_allclose(e["radiance_g"][i], lamp.floor_rho[1] * got[1] / math.pi,
                                   rtol=1e-9)
        worst_law = max(worst_law, float(np.max(np.abs(got / law - 1))))
        worst_exact = max(worst_exact, float(np.max(np.abs(got / exact - 1))))
    # every floor element against the law
    fl = np.flatnonzero(e["material"] == "floor")
    c = np.column_stack([e[f"center_{k}"][fl] for k in "xyz"])
    d2 = np.sum((c - poly.mean(0)) ** 2, axis=1)
    law = 683.0 * (Y @ le) * area * lamp.height ** 2 / d2 ** 2
    floor_worst = float(np.max(np.abs(e["illuminance"][fl] / law - 1)))
    assert floor_worst < 0.01
    print(f"{method}: worst relative difference at the 5 points: inverse-square law "
          f"{worst_law:.2e}, exact {worst_exact:.2e}; over the {len(fl)} floor elements "
          f"against the law {floor_worst:.2e}")
    # the lamp reflects nothing: its irradiance is undefined, its luminance is 683 Y(Le)
    lamp_row = np.flatnonzero(e["material"] == "lamp")
    assert np.all(np.isnan(e["illuminance"][lamp_row]))
    np.testing.assert_allclose(e["luminance"][lamp_row], 683.0 * Y @ le)
    # the files and the report of the render
    for name in ("elements.csv", "surfaces.csv", "materials.csv"):
        assert os.path.getsize(os.path.join(lamp_run, name)) > 0
    light = json.load(open(os.path.join(lamp_run, "report.json")))["light"]
    floor = next(r for r in light["materials"] if r["material"] == "floor")
    assert floor["illuminance_max"] == pytest.approx(683.0 * Y @ le * area / lamp.height ** 2,
                                                     rel=0.01)
    assert floor["area"] == pytest.approx(4.0)
    has_arrow = True
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        has_arrow = False
    assert os.path.exists(os.path.join(lamp_run, "elements.parquet")) == has_arrow
