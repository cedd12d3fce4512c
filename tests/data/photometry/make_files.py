"""Writes the hand-made photometric files of this folder (run it here; each file's formula is
in its [TEST] line and in tests/formats/test_photometry.py). Not part of the test run."""

import numpy as np


def ies(name, header, kind, v, h, T, mult=1.0, bf=1.0, blpf=1.0, lamps=(1, -1), tilt="NONE"):
    lines = header + [f"TILT={tilt}", f"{lamps[0]} {lamps[1]} {mult:g} {len(v)} {len(h)} {kind} 2 0 0 0",
                      f"{bf:g} {blpf:g} 10"]

    def wrap(vals):
        vals = [f"{x:.10g}" for x in vals]
        return [" ".join(vals[i:i + 10]) for i in range(0, len(vals), 10)]
    lines += wrap(v) + wrap(h)
    for row in T:
        lines += wrap(row)
    open(name, "w").write("\r\n".join(lines) + "\r\n")


def ldt(name, isym, mc, dc, G, I, flux=2000.0, lamps=1, cf=1.0):
    L = ["radiosity tests (hand-made)", "1", str(isym), str(mc), f"{dc:g}", str(len(G)), f"{G[1] - G[0]:g}",
         "report", name, "0", name, "2026-12-08", "100", "100", "50", "90", "90", "0", "0", "0", "0",
         "100", "80", f"{cf:g}", "0", "1", str(lamps), "LED", f"{flux:g}", "3000", "80", "20"]
    L += ["0.5"] * 10
    L += [f"{k * dc:g}" for k in range(mc)] + [f"{g:g}" for g in G] + [f"{x:.10g}" for x in np.ravel(I)]
    open(name, "w").write("\r\n".join(L) + "\r\n")


g = np.arange(0, 181, 5.0)
ies("isotropic.ies", ["IESNA:LM-63-2002", "[TEST] isotropic point source, 1000 cd, hand-made",
                      "[MANUFAC] radiosity tests", "[LUMCAT] ISO-1000"], 1, g, [0.0], [np.full(len(g), 1000.0)])
g2 = np.arange(0, 91, 2.0)
ies("cosine.ies", ["IESNA:LM-63-1995", "[TEST] Lambertian downlight I = 1000 cos(gamma), multiplier 2"], 1, g2,
    [0.0], [500.0 * np.cos(np.radians(g2))], mult=2.0)
h = np.arange(0, 360, 15.0)
g3 = np.arange(0, 181, 10.0)
ies("asymmetric.ies", ["IESNA91", "[TEST] I = 100 + 60 sin(gamma) (1 + cos C) + C / 3, C 0-345",
                       "[_NOTE] ballast factor 0.5, lamp factor 2"], 1, g3, h,
    [100 + 60 * np.sin(np.radians(g3)) * (1 + np.cos(np.radians(c))) + c / 3.0 for c in h], bf=0.5, blpf=2.0)
for nm, hh in (("bilateral.ies", np.arange(0, 181, 30.0)), ("quadrant.ies", np.arange(0, 91, 30.0)),
               ("bilateral90.ies", np.arange(90, 271, 30.0))):
    ies(nm, ["IESNA:LM-63-2002", f"[TEST] {nm}: I = 200 + C (as given)"], 1, g3, hh, [200 + c + 0 * g3 for c in hh])
ies("lm63-1986.ies", ["hand-made 1986 file, no keywords"], 1, g, [0.0], [np.full(len(g), 250.0)])
Hb = np.arange(-90, 91, 10.0)
Vb = np.arange(-90, 91, 10.0)
ies("typeb.ies", ["IESNA:LM-63-2002", "[TEST] type B: I = 1000 cos H cos V"], 2, Vb, Hb,
    [1000 * np.cos(np.radians(x)) * np.cos(np.radians(Vb)) for x in Hb])
ies("typea.ies", ["IESNA:LM-63-2002", "[TEST] type A: I = 1000 cos H cos V, H 0..90 (symmetric)"], 3, Vb, Hb[9:],
    [1000 * np.cos(np.radians(x)) * np.cos(np.radians(Vb)) for x in Hb[9:]])
ies("tilt-include.ies", ["IESNA:LM-63-2002"], 1, g, [0.0], [np.full(len(g), 1.0)], tilt="INCLUDE")
G = np.arange(0, 181, 5.0)
ldt("isotropic.ldt", 1, 1, 0, G, np.full(len(G), 500.0))          # 500 cd/klm x 2 klm = 1000 cd
G2 = np.arange(0, 91, 10.0)
ldt("quadrant.ldt", 4, 24, 15, G2, [np.full(len(G2), 300 + 2 * c) for c in np.arange(0, 91, 15.0)])
ldt("bilateral.ldt", 2, 24, 15, G2, [np.full(len(G2), 300 + 2 * c) for c in np.arange(0, 181, 15.0)])
ldt("bilateral90.ldt", 3, 24, 15, G2, [np.full(len(G2), 300 + 2 * c) for c in np.arange(90, 271, 15.0)])
ldt("full.ldt", 0, 24, 15, G2, [np.full(len(G2), 300 + 2 * c) for c in np.arange(0, 360, 15.0)])
with open("bad-number.ies", "w") as f:
    f.write("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 10\n0 90 180\n0\n100 abc 100\n")
with open("truncated.ies", "w") as f:
    f.write("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 10\n0 90 180\n0\n100 100\n")
