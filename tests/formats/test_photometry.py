"""IES LM-63 and EULUMDAT readers (formats/photometry.py) on hand-made files (tests/data/photometry,
each with a known formula): values at the table's angles, bilinear between them, symmetry
unfolding and wrap-around, multipliers and ballast factors, the flux integral against the
formula's exact flux, the three photometric types, and one-line errors for bad files."""

from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest

from radiosity.formats.photometry import PhotometryError, read_photometry

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                    "photometry")


def ph(name):
    return read_photometry(os.path.join(DATA, name))


def c_dir(C, g):
    """Unit local direction of type C angles (degrees): x along C0, y along C90, z the nadir."""
    C, g = np.radians(np.asarray(C, float)), np.radians(np.asarray(g, float))
    return np.stack([np.sin(g) * np.cos(C), np.sin(g) * np.sin(C), np.cos(g)], axis=-1).reshape(-1, 3)


@pytest.mark.parametrize("name", ["isotropic.ies", "isotropic.ldt"])
def test_isotropic_everywhere_and_its_flux(name, rng):
    p = ph(name)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.allclose(p.intensity(d), 1000.0, rtol=1e-9)
    assert p.flux() == pytest.approx(4 * math.pi * 1000.0, rel=1e-9)


def test_1986_file_without_header():
    p = ph("lm63-1986.ies")
    assert np.allclose(p.intensity(c_dir([0, 90, 200], [0, 90, 170])), 250.0)


def test_cosine_downlight_multiplier_and_flux():
    """I = 1000 cos gamma over the lower hemisphere (the file: 500 cos gamma, multiplier 2);
    nothing above the horizon (the table ends at 90 degrees)."""
    p = ph("cosine.ies")
    g = np.array([0.0, 30.0, 60.0, 89.0])
    got = p.intensity(c_dir(np.zeros(4), g))
    # bilinear between 2 degree steps: within the chord error of cos (1e-3 relative here)
    assert np.allclose(got, 1000 * np.cos(np.radians(g)), rtol=2e-3, atol=0.1)
    assert got[0] == pytest.approx(1000.0, rel=1e-9)
    assert p.intensity(c_dir([0.0, 77.0], [95.0, 150.0])).max() == 0.0
    assert p.flux() == pytest.approx(math.pi * 1000.0, rel=2e-3)


def asym(C, g):
    """The formula of asymmetric.ies (cd), times its ballast factor 0.5 and lamp factor 2 (the
    file holds it to 6 figures: comparisons at 2e-6)."""
    return 100 + 60 * np.sin(np.radians(g)) * (1 + np.cos(np.radians(C))) + C / 3.0


def test_asymmetric_table_values_bilinear_and_wrap():
    p = ph("asymmetric.ies")
    # at the table's angles: exact
    C = np.array([0.0, 15.0, 90.0, 345.0, 180.0])
    g = np.array([0.0, 40.0, 90.0, 130.0, 170.0])
    assert np.allclose(p.intensity(c_dir(C, g)), asym(C, g), rtol=2e-6)
    # between: bilinear in (C, gamma)
    c0, c1, g0, g1 = 30.0, 45.0, 50.0, 60.0
    s, t = 0.25, 0.7
    want = ((1 - s) * ((1 - t) * asym(c0, g0) + t * asym(c0, g1))
            + s * ((1 - t) * asym(c1, g0) + t * asym(c1, g1)))
    assert p.intensity(c_dir([c0 + s * 15], [g0 + t * 10]))[0] == pytest.approx(want, rel=2e-6)
    # wrap-around: between C = 345 and C = 360 (= 0)
    a, b = asym(345.0, 60.0), asym(0.0, 60.0)
    assert p.intensity(c_dir([355.0], [60.0]))[0] == pytest.approx(a + (b - a) * 10 / 15, rel=2e-6)
    assert p.intensity(c_dir([-5.0], [60.0]))[0] == pytest.approx(a + (b - a) * 10 / 15, rel=2e-6)


@pytest.mark.parametrize("name", ["quadrant.ies", "bilateral.ies", "bilateral90.ies"])
def test_horizontal_symmetries_unfold(name):
    """I = 200 + C on the planes the file gives, mirrored as LM-63 says elsewhere."""
    p = ph(name)
    given = {"quadrant.ies": (0, 90), "bilateral.ies": (0, 180), "bilateral90.ies": (90, 270)}[name]
    for C in (0.0, 20.0, 75.0, 100.0, 170.0, 200.0, 250.0, 300.0, 350.0):
        c = C
        if name == "quadrant.ies":
            c = C % 180.0
            c = 180.0 - c if c > 90 else c
        elif name == "bilateral.ies":
            c = 360.0 - C if C > 180 else C
        elif not 90 <= C <= 270:
            c = 180.0 - C if C < 90 else 540.0 - C
        assert given[0] <= c <= given[1]
        assert p.intensity(c_dir([C], [45.0]))[0] == pytest.approx(200 + c, rel=1e-12), C


@pytest.mark.parametrize("name", ["quadrant.ldt", "bilateral.ldt", "bilateral90.ldt", "full.ldt"])
def test_ldt_symmetries(name):
    """I = (300 + 2 C) cd/klm x 2 klm on every plane the symmetry Isym implies."""
    p = ph(name)
    for C in (0.0, 15.0, 50.0, 95.0, 170.0, 190.0, 260.0, 285.0, 350.0):
        c = C
        if name == "quadrant.ldt":
            c = C % 180.0
            c = 180.0 - c if c > 90 else c
        elif name == "bilateral.ldt":
            c = 360.0 - C if C > 180 else C
        elif name == "bilateral90.ldt" and not 90 <= C <= 270:
            c = 180.0 - C if C < 90 else 540.0 - C
        if name == "full.ldt" and C > 345:       # between C345 and C360 = C0: wrapped
            want = 2 * (990.0 + (300.0 - 990.0) * (C - 345) / 15)
            assert p.intensity(c_dir([C], [30.0]))[0] == pytest.approx(want, rel=1e-9)
            continue
        assert p.intensity(c_dir([C], [30.0]))[0] == pytest.approx(2 * (300 + 2 * c), rel=1e-12), C


@pytest.mark.parametrize("name, kind", [("typeb.ies", "B"), ("typea.ies", "A")])
def test_types_a_and_b(name, kind):
    """I = 1000 cos H cos V: on the beam axis 1000, off it by the type's own angles, nothing
    behind; flux against the exact integral (type B: dw = cos H dH dV over H, V in +-90:
    1000 pi / 2 x 2; type A: dw = cos V, the same)."""
    p = ph(name)
    assert p.kind == kind
    assert p.intensity(np.array([[0.0, 0.0, 1.0]]))[0] == pytest.approx(1000.0)
    assert p.intensity(np.array([[0.0, 0.0, -1.0]]))[0] == 0.0
    # a direction in the plane through the beam axis and p (x): type B's V, type A's V = asin x
    a = math.radians(40.0)
    d = np.array([[math.sin(a), 0.0, math.cos(a)]])
    assert p.intensity(d)[0] == pytest.approx(1000 * math.cos(a), rel=1e-9)
    # toward -q: positive H; toward +q: negative H (the same by the symmetric formula)
    d = np.array([[0.0, -math.sin(a), math.cos(a)], [0.0, math.sin(a), math.cos(a)]])
    assert np.allclose(p.intensity(d), 1000 * math.cos(a), rtol=1e-9)
    # both angles off the axis at table points (H = 30, V = 20): the exact table value
    H, V = math.radians(30.0), math.radians(20.0)
    if kind == "B":    # H = asin(-y), V = atan2(x, z)
        y = -math.sin(H)
        x, z = math.cos(H) * math.sin(V), math.cos(H) * math.cos(V)
    else:              # H = atan2(-y, z), V = asin(x)
        x = math.sin(V)
        y, z = -math.cos(V) * math.sin(H), math.cos(V) * math.cos(H)
    assert p.intensity(np.array([[x, y, z]]))[0] == pytest.approx(1000 * math.cos(H) * math.cos(V),
                                                                  rel=1e-9)
    # exact: dw = cos(latitude) d(latitude) d(plane angle), so the flux is 1000 times the
    # integral of cos^2 over the latitude (pi / 2) times that of cos over the plane angle (2);
    # the table's bilinear chords of cos over 10 degree steps lose 0.5 %
    assert p.flux() == pytest.approx(1000 * math.pi, rel=1e-2)


def fibonacci(n):
    """n nearly uniform unit directions (a Fibonacci sphere): equal solid angle each."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    r = np.sqrt(1 - z * z)
    phi = k * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@pytest.mark.parametrize("name", ["cosine.ies", "asymmetric.ies", "quadrant.ies",
                                  "bilateral90.ies", "typeb.ies", "typea.ies", "full.ldt",
                                  "bilateral90.ldt"])
def test_flux_is_the_integral_of_the_interpolated_intensity(name):
    """flux() (exact per cell) against brute force: the mean of intensity() over 10^6 equal
    solid angles times 4 pi, whatever the type, symmetry and angle mapping."""
    p = ph(name)
    brute = p.intensity(fibonacci(1_000_000)).mean() * 4 * math.pi
    assert p.flux() == pytest.approx(brute, rel=2e-4)


def test_ies_and_ldt_agree_in_their_common_table():
    a, b = ph("isotropic.ies"), ph("isotropic.ldt")
    assert a.flux() == pytest.approx(b.flux(), rel=1e-9)


@pytest.mark.parametrize("name, words", [
    ("tilt-include.ies", ["tilt-include.ies", "line 2", "TILT=INCLUDE"]),
    ("bad-number.ies", ["bad-number.ies", "line 7", "'abc'"]),
    ("truncated.ies", ["truncated.ies", "ends after 2 of the 3 candela values"]),
    ("nothing.ies", ["not found", "nothing.ies"]),
    ("isotropic.txt", ["unknown photometric file type"]),
])
def test_bad_files_one_line(name, words, tmp_path):
    path = os.path.join(DATA, name)
    if name == "isotropic.txt":
        path = str(tmp_path / name)
        open(path, "w").write("x")
    with pytest.raises(PhotometryError) as e:
        read_photometry(path)
    msg = str(e.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


def test_bad_ldt_and_no_tilt(tmp_path):
    p = tmp_path / "short.ldt"
    p.write_text("maker\n1\n7\n1\n0\n5\n")
    with pytest.raises(PhotometryError, match=r"short.ldt: line 3: symmetry indicator Isym 7"):
        read_photometry(str(p))
    q = tmp_path / "noties.ies"
    q.write_text("IESNA:LM-63-2002\n[TEST] x\n1 2 3\n")
    with pytest.raises(PhotometryError, match=r"noties.ies: no TILT= line"):
        read_photometry(str(q))


def _ies2rad(fn, tmp_path):
    """(candela grid (nh, nv) or (nv,), horizontal angles, vertical angles) of `fn` as Radiance's
    ies2rad converts it: its data file times its multiplier, source area and 179 lm/W."""
    import subprocess

    pyradiance = pytest.importorskip("pyradiance")
    P = os.path.dirname(pyradiance.__file__)
    env = dict(os.environ, PATH=os.path.join(P, "bin") + os.pathsep + os.environ["PATH"],
               RAYPATH="." + os.pathsep + os.path.join(P, "lib"))
    shutil.copy(fn, tmp_path / "lum.ies")
    subprocess.run(["ies2rad", "-t", "default", "-o", "lum", "lum.ies"], cwd=tmp_path, env=env,
                   check=True, capture_output=True)
    rad = (tmp_path / "lum.rad").read_text().split("\n")
    k = next(i for i, ln in enumerate(rad) if "brightdata" in ln)
    mult = float(rad[k + 3].split()[1])
    radius = float(next(ln for ln in rad if ln.startswith("4 0 0 0")).split()[4])
    tok = (tmp_path / "lum.dat").read_text().split()
    nd = int(tok[0])
    axes = []
    for d in range(nd):
        a, b, n = float(tok[1 + 3 * d]), float(tok[2 + 3 * d]), int(tok[3 + 3 * d])
        axes.append(np.linspace(a, b, n))
    vals = np.array(tok[1 + 3 * nd:], float).reshape([len(a) for a in axes])
    cd = vals * mult * 179.0 * math.pi * radius ** 2
    return cd, (axes[0] if nd == 2 else np.array([0.0])), axes[-1]


@pytest.mark.parametrize("name", ["asymmetric.ies", "cosine.ies", "quadrant.ies",
                                  "bilateral.ies", "lm63-1986.ies"])
def test_candela_agree_with_radiance_ies2rad(name, tmp_path):
    """Our table (multiplier, ballast and lamp factors, angles) against the one Radiance's
    ies2rad writes for the same file, at every angle it gives."""
    cd, H, V = _ies2rad(os.path.join(DATA, name), tmp_path)
    p = ph(name)
    hh, vv = np.meshgrid(H, V, indexing="ij")
    ours = p.at(hh, vv).reshape(cd.shape)
    assert np.allclose(ours, cd, rtol=2e-5, atol=1e-9)
