"""The CLI on scenes with [[luminaire]] tables: a bad photometric file or a luminaire inside a
solid is one line `error: ...` and exit status 2 before anything starts; a scene lit only by a
luminaire plans with no warning and says its luminaires and where their light is taken."""

from __future__ import annotations

import os
import shutil

from click.testing import CliRunner

from radiosity.cli.commands import main
from helpers import FLOOR_AND_TRIANGLE, write_scene
from test_badinput import one_line_error

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                    "photometry")
GREY = "[material.default]\nreflectance = [0.5, 0.5, 0.5]\n"


def test_bad_photometric_file_is_one_line(tmp_path):
    shutil.copy(os.path.join(DATA, "bad-number.ies"), tmp_path / "lamp.ies")
    path = write_scene(tmp_path, FLOOR_AND_TRIANGLE,
                       GREY + '[[luminaire]]\nies = "lamp.ies"\nposition = [0.5, 1.5, 0.5]\n')
    r = CliRunner().invoke(main, ["plan", path])
    one_line_error(r, "lamp.ies", "line 7", "'abc' is not a number")
    r = CliRunner().invoke(main, ["render", path, "--out", str(tmp_path / "out")])
    one_line_error(r, "lamp.ies")
    assert not os.path.exists(tmp_path / "out")


def test_luminaire_inside_a_solid_is_one_line(tmp_path):
    cube = "".join(f"v {x} {y} {z}\n" for x, y, z in
                   [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1),
                    (0, 1, 1)]) + "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n"
    path = write_scene(tmp_path, cube, GREY + '[[luminaire]]\nname = "in"\n'
                       'position = [0.5, 0.5, 0.5]\nintensity_cd = 100\n',
                       camera="[camera]\nposition = [3, 3, 3]\nlook_at = [0.5, 0.5, 0.5]\n"
                              "up = [0, 0, 1]\nfov_y = 40\nresolution = [16, 16]\n")
    r = CliRunner().invoke(main, ["plan", path])
    one_line_error(r, "[[luminaire]] 'in'", "inside a wall or a closed solid")


def test_scene_lit_only_by_a_luminaire_plans_without_warning(tmp_path):
    path = write_scene(tmp_path, FLOOR_AND_TRIANGLE,
                       GREY + '[[luminaire]]\nposition = [0.5, 1.5, 0.5]\nintensity_cd = 100\n')
    r = CliRunner().invoke(main, ["plan", path])
    assert r.exit_code == 0, r.output
    assert "warning:" not in r.output and "no element emits light" not in r.output, r.output
    assert "1 luminaire(s), 1256.6 lm" in r.output and "direct light: points" in r.output
    assert "method: hierarchical" in r.output


def test_pairs_method_or_links_with_luminaires_is_refused_up_front(tmp_path):
    path = write_scene(tmp_path, FLOOR_AND_TRIANGLE,
                       GREY + '[[luminaire]]\nposition = [0.5, 1.5, 0.5]\nintensity_cd = 100\n')
    r = CliRunner().invoke(main, ["render", path, "--method", "pairs", "--out",
                                  str(tmp_path / "out")])
    one_line_error(r, "the pairs method cannot carry", "1 luminaire(s)")
    assert not os.path.exists(tmp_path / "out")
    r = CliRunner().invoke(main, ["plan", path, "--direct", "links"])
    one_line_error(r, "direct.mode = links cannot carry")
