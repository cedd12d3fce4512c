"""Walkthroughs (stages/walkthrough.py): the camera path's spline goes through its keyframes,
every frame is a view of the one solved run (the same image as render_view from that frame's
camera), the video is written and readable, and a bad path file is one line naming the file
and the key."""

from __future__ import annotations

import os

import numpy as np
import pytest
from click.testing import CliRunner

from helpers import scene_path
from radiosity.settings import options as settings_of

PATH = """\
frames = 5
fps = 10
resolution = 16
fov_y = 60
[[keyframe]]
position = [378, 300, 100]
look_at = [278, 200, 400]
[[keyframe]]
position = [278, 400, 60]
look_at = [278, 150, 350]
up = [0, 1, 0.2]
[[keyframe]]
position = [178, 300, 100]
look_at = [278, 200, 400]
fov_y = 50
"""


def _path(tmp_path, text=PATH, name="orbit.toml"):
    fn = tmp_path / name
    fn.write_text(text)
    return str(fn)


# ----------------------------------------------------------------------------- the spline

def test_the_spline_goes_through_its_keyframes_exactly(tmp_path):
    from radiosity.stages.walkthrough import load_path

    p = load_path(_path(tmp_path))
    assert p.frames == 5 and np.array_equal(p.times, [0.0, 0.2, 0.4])
    at = p.at(p.times)
    assert np.array_equal(at["position"], p.position)
    assert np.array_equal(at["look_at"], p.look_at)
    assert np.array_equal(at["fov_y"], [60.0, 60.0, 50.0])
    # frames 0, 2 and 4 fall on the keyframes: their cameras stand there
    cams = p.cameras()
    for k, j in ((0, 0), (2, 1), (4, 2)):
        assert np.allclose(cams[k].center, p.position[j], rtol=0, atol=1e-9)
        z = p.look_at[j] - p.position[j]
        assert np.allclose(cams[k].z, z / np.linalg.norm(z), atol=1e-12)
    assert (cams[0].width, cams[0].height) == (16, 16)
    # between keyframes: smooth, not the straight line (the middle keyframe pulls it up)
    mid = p.at([0.1])["position"][0]
    assert mid[1] > 350.0 and abs(mid[0] - 328.0) < 15.0


def test_two_keyframes_make_a_straight_line_and_times_set_the_frames(tmp_path):
    from radiosity.stages.walkthrough import hermite, load_path

    t = np.linspace(0, 3, 7)
    line = hermite(np.array([0.0, 3.0]), np.array([[0.0, 0, 0], [3.0, 6, 9]]), t)
    assert np.allclose(line, t[:, None] * [1, 2, 3], atol=1e-12)
    p = load_path(_path(tmp_path, "fps = 4\n[[keyframe]]\nposition = [0, 0, 0]\n"
                                  "look_at = [0, 0, 1]\ntime = 1.0\n[[keyframe]]\n"
                                  "position = [1, 0, 0]\nlook_at = [1, 0, 1]\ntime = 3.5\n"))
    assert p.frames == 11 and np.allclose(p.frame_times(), np.linspace(1.0, 3.5, 11))
    p = load_path(_path(tmp_path, PATH), {"frames": 9})  # --frames keeps keyframes on frames
    assert p.frames == 9 and np.array_equal(p.at(p.frame_times()[[0, 4, 8]])["position"],
                                            p.position)


BAD = [
    ("[[keyframe]]\nposition = [0, 0, 0]\n", "[[keyframe]] 1 needs 'look_at'"),
    ("[[keyframe]]\nposition = [0, 0]\nlook_at = [0, 0, 1]\n", "[[keyframe]] 1 position"),
    ("[[keyframe]]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\nfov = 40\n", "'fov'"),
    ("fps = 0\n[[keyframe]]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\n", "fps"),
    ("[[keyframe]]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\ntime = 2\n"
     "[[keyframe]]\nposition = [1, 0, 0]\nlook_at = [0, 0, 1]\ntime = 1\n",
     "[[keyframe]] 2 time"),
    ("frames = 3\n", "no [[keyframe]]"),
    ("frames = [\n", "not valid TOML"),
]


@pytest.mark.parametrize("text,says", BAD)
def test_a_bad_path_file_is_one_line_naming_the_file_and_key(tmp_path, text, says):
    from radiosity.cli.commands import main

    fn = _path(tmp_path, text, "bad.toml")
    r = CliRunner().invoke(main, ["walkthrough", str(tmp_path / "no-run"), "--path", fn])
    assert r.exit_code == 2, r.output
    line = r.output.strip()
    assert "\n" not in line and line.startswith("error:") and fn in line and says in line, line


def test_an_unknown_video_format_is_refused(tmp_path):
    from radiosity.cli.commands import main

    r = CliRunner().invoke(main, ["walkthrough", str(tmp_path), "--path", _path(tmp_path),
                                  "--out", str(tmp_path / "a.xyz")])
    assert r.exit_code == 2 and ".mp4" in r.output and "a.xyz" in r.output


# ----------------------------------------------------------------------------- frames and videos

@pytest.fixture(scope="module")
def run(tmp_path_factory):
    import radiosity

    d = tmp_path_factory.mktemp("walk")
    radiosity.render(scene_path("cornell-box"), out=str(d / "cb"), resolution=16)
    return d


@pytest.mark.cluster
def test_frames_are_views_of_the_run_and_the_video_reads_back(run, tmp_path):
    import imageio.v3 as iio

    from radiosity.runtime.store import RunStore
    from radiosity.stages.views import render_view
    from radiosity.stages.walkthrough import load_path, render_walkthrough

    fn = _path(tmp_path)
    frames = {}
    w = render_walkthrough(str(run / "cb"), fn, progress=False,
                           on_frame=lambda k, img, fig: frames.setdefault(k, img),
                           settings=settings_of())
    assert w.frames == 5 and os.path.basename(w.folder) == "orbit"
    assert sorted(f for f in os.listdir(w.folder) if f.endswith(".png")) == [
        f"frame-{k:04d}.png" for k in range(1, 6)]
    cams = load_path(fn).cameras(RunStore(str(run / "cb")).load_camera())
    for k in (0, 3):  # each frame: the view render_view makes from that frame's camera alone
        v = render_view(str(run / "cb"), cams[k], name=f"frame{k}", settings=settings_of())
        assert np.allclose(frames[k], v.image, rtol=1e-9, atol=1e-12)
        assert frames[k].mean() > 0
    assert not np.allclose(frames[0], frames[2])  # the camera moves
    video = list(iio.imiter(w.video, plugin="FFMPEG"))
    assert len(video) == 5 and video[0].shape == (16, 16, 3)
    assert w.figures["frames"] == 5 and w.figures["time_per_frame_s"] > 0


@pytest.mark.cluster
def test_the_cli_writes_gif_and_webp(run, tmp_path):
    from PIL import Image

    from radiosity.cli.commands import main

    fn = _path(tmp_path)
    for ext in ("gif", "webp"):
        out = tmp_path / f"walk.{ext}"
        r = CliRunner().invoke(main, ["walkthrough", str(run / "cb"), "--path", fn, "--out",
                                      str(out), "--frames", "3", "--resolution", "20x12",
                                      "--name", f"w-{ext}", "--no-keep-frames"])
        assert r.exit_code == 0, r.output
        im = Image.open(out)
        assert im.n_frames == 3 and im.size == (20, 12)
        assert not [f for f in os.listdir(run / "cb" / "walkthroughs" / f"w-{ext}")
                    if f.endswith(".png")]
