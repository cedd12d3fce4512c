"""Walkthroughs (issue 28): a camera path (keyframes in a TOML file) interpolated into frames,
each a view of ONE solved run (stages/views.Viewer opens the run once for all frames), written
as PNG frames in RUN/walkthroughs/NAME/ and encoded into a video (MP4 through imageio's ffmpeg
plugin, animated GIF or WebP through Pillow, by the output file's extension).

The path: positions, look-at points, up vectors and fields of view are interpolated by one
cubic Hermite spline in time with Catmull-Rom tangents (m_i = (p_{i+1} - p_{i-1}) /
(t_{i+1} - t_{i-1}), one-sided at the ends): C1, through every keyframe exactly, and straight
for two keyframes. Frames are evenly spaced in time from the first keyframe to the last.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from radiosity.core.bundles import Camera
from radiosity.errors import RadiosityError

#: Frames of a path whose keyframes have no times and which gives no `frames`.
DEFAULT_FRAMES = 30
DEFAULT_FPS = 24.0
#: Output formats by extension: ffmpeg containers, and Pillow's animated formats.
VIDEO = (".mp4", ".mkv", ".mov", ".avi")
ANIMATED = (".gif", ".webp")

_TOP_KEYS = {"frames", "fps", "resolution", "up", "fov_y", "keyframe", "name"}
_KEY_KEYS = {"position", "look_at", "up", "fov_y", "time"}


class PathError(RadiosityError, ValueError):
    """A camera path file that cannot be used: names the file and the key."""


@dataclass(frozen=True)
class CameraPath:
    """Keyframes and their times. times (K,) float64 seconds, strictly increasing;
    position, look_at, up (K, 3) float64 (world units); fov_y (K,) float64 degrees (nan: the
    run's); frames: how many; fps; resolution (W, H) or None (the run's); source: the file."""

    times: np.ndarray
    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov_y: np.ndarray
    frames: int
    fps: float
    resolution: tuple[int, int] | None = None
    source: str = "the camera path"
    name: str | None = None

    def frame_times(self) -> np.ndarray:
        """(frames,) float64: evenly spaced from the first keyframe's time to the last's."""
        if self.frames == 1:
            return self.times[:1].copy()
        return np.linspace(self.times[0], self.times[-1], self.frames)

    def at(self, t) -> dict:
        """The interpolated position, look_at, up (F, 3) and fov_y (F,) at times t (F,)."""
        t = np.atleast_1d(np.asarray(t, float))
        return {k: hermite(self.times, getattr(self, k), t) for k in ("position", "look_at", "up")
                } | {"fov_y": hermite(self.times, self.fov_y[:, None], t)[:, 0]}

    def cameras(self, run_camera: Camera | None = None) -> list[Camera]:
        """The frames' cameras, at the path's resolution (else the run camera's), with the
        run camera's field of view where the path gives none."""
        from radiosity.scene.load import parse_camera

        res = self.resolution
        fov = self.fov_y
        if run_camera is not None:
            if res is None:
                res = (run_camera.width, run_camera.height)
            run_fov = math.degrees(2 * math.atan(run_camera.half_h / run_camera.focal))
            fov = np.where(np.isnan(fov), run_fov, fov)
        if res is None or np.isnan(fov).any():
            raise PathError(f"{self.source}: give resolution and fov_y (or the run's camera)")
        path = CameraPath(self.times, self.position, self.look_at, self.up, fov, self.frames,
                          self.fps, res, self.source, self.name)
        v = path.at(path.frame_times())
        cams = []
        for k in range(self.frames):
            try:
                cams.append(parse_camera({"position": v["position"][k].tolist(),
                                          "look_at": v["look_at"][k].tolist(),
                                          "up": v["up"][k].tolist(),
                                          "fov_y": float(v["fov_y"][k])},
                                         f"{self.source} (frame {k + 1})", res))
            except RadiosityError as e:
                raise PathError(str(e)) from None
        return cams


def hermite(times: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The cubic Hermite spline through (times (K,), values (K, D)) with Catmull-Rom tangents
    for non-uniform times, at t (F,): (F, D) float64. Exactly the keyframe's value at its
    time; linear for K = 2; constant for K = 1; t outside the keyframes is clamped."""
    times = np.asarray(times, float)
    p = np.asarray(values, float)
    t = np.clip(np.asarray(t, float), times[0], times[-1])
    K = len(times)
    if K == 1:
        return np.repeat(p[:1], len(t), axis=0)
    m = np.empty_like(p)
    m[0] = (p[1] - p[0]) / (times[1] - times[0])
    m[-1] = (p[-1] - p[-2]) / (times[-1] - times[-2])
    if K > 2:
        m[1:-1] = (p[2:] - p[:-2]) / (times[2:] - times[:-2])[:, None]
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, K - 2)
    h = times[i + 1] - times[i]
    s = ((t - times[i]) / h)[:, None]
    h00 = (1 + 2 * s) * (1 - s) ** 2
    h10 = s * (1 - s) ** 2
    h01 = s * s * (3 - 2 * s)
    h11 = s * s * (s - 1)
    return h00 * p[i] + h10 * h[:, None] * m[i] + h01 * p[i + 1] + h11 * h[:, None] * m[i + 1]


# ----------------------------------------------------------------------------- the path file

def load_path(fn: str, overrides: dict | None = None) -> CameraPath:
    """A camera path from a TOML file:

        frames = 30              # default: fps x duration + 1 with keyframe times, else 30
        fps = 24                 # default 24
        resolution = 128         # N, [W, H] or "WxH"; default: the run's
        up = [0, 1, 0]           # every keyframe's default (default +y)
        fov_y = 60               # every keyframe's default (default: the run camera's)
        [[keyframe]]             # at least one
        position = [x, y, z]
        look_at = [x, y, z]
        time = 0.0               # seconds; all keyframes or none (then evenly spaced)
        up = [...]; fov_y = ...  # optional

    `overrides` replace top-level keys (the command's --frames, --fps, --resolution).
    Raises PathError naming the file and the key."""
    from radiosity.scene.load import read_toml

    data = read_toml(fn, "--path", PathError)
    return parse_path({**data, **(overrides or {})}, fn)


def parse_path(data: dict, fn: str = "the camera path") -> CameraPath:
    """CameraPath from the TOML table `data` of file `fn` (see load_path)."""
    from radiosity.scene.load import parse_resolution

    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise PathError(f"{fn}: unknown key(s) {sorted(unknown)}; a camera path takes "
                        f"{sorted(_TOP_KEYS - {'keyframe'})} and [[keyframe]] tables")
    keys = data.get("keyframe")
    if not isinstance(keys, list) or not keys or not all(isinstance(k, dict) for k in keys):
        raise PathError(f"{fn}: no [[keyframe]] tables (each with position and look_at)")
    up0 = _vec(data.get("up", [0.0, 1.0, 0.0]), "up", fn)
    fov0 = _fov(data["fov_y"], "fov_y", fn) if "fov_y" in data else math.nan
    rows = []
    for j, k in enumerate(keys, 1):
        where = f"[[keyframe]] {j}"
        bad = set(k) - _KEY_KEYS
        if bad:
            raise PathError(f"{fn}: {where}: unknown key(s) {sorted(bad)}; a keyframe takes "
                            f"{sorted(_KEY_KEYS)}")
        for need in ("position", "look_at"):
            if need not in k:
                raise PathError(f"{fn}: {where} needs '{need}'")
        rows.append((_vec(k["position"], f"{where} position", fn),
                     _vec(k["look_at"], f"{where} look_at", fn),
                     _vec(k["up"], f"{where} up", fn) if "up" in k else up0,
                     _fov(k["fov_y"], f"{where} fov_y", fn) if "fov_y" in k else fov0,
                     _num(k["time"], f"{where} time", fn) if "time" in k else None))
    timed = [r[4] is not None for r in rows]
    if any(timed) and not all(timed):
        raise PathError(f"{fn}: [[keyframe]] {timed.index(False) + 1} has no 'time': give every "
                        "keyframe a time, or none (evenly spaced)")
    fps = _num(data.get("fps", DEFAULT_FPS), "fps", fn)
    if not fps > 0:
        raise PathError(f"{fn}: fps must be positive, got {data.get('fps')!r}")
    if all(timed):
        times = np.array([r[4] for r in rows], float)
        if len(times) > 1 and not np.all(np.diff(times) > 0):
            j = int(np.nonzero(np.diff(times) <= 0)[0][0]) + 2
            raise PathError(f"{fn}: [[keyframe]] {j} time: keyframe times must increase, got "
                            f"{times[j - 2]:g} then {times[j - 1]:g}")
        frames = round((times[-1] - times[0]) * fps) + 1
    else:
        frames = DEFAULT_FRAMES if len(rows) > 1 else 1
        times = np.arange(len(rows), dtype=float) * max(1, frames - 1) / max(1, len(rows) - 1) / fps
    if "frames" in data:
        fr = data["frames"]
        if isinstance(fr, bool) or not isinstance(fr, int) or fr < 1:
            raise PathError(f"{fn}: frames must be a positive whole number, got {fr!r}")
        frames = fr
        if not all(timed):  # keyframes evenly spaced over the frames
            times = (np.arange(len(rows), dtype=float) * max(1, frames - 1)
                     / max(1, len(rows) - 1) / fps)
    res = (parse_resolution(data["resolution"], f"{fn}: resolution")
           if "resolution" in data else None)
    name = data.get("name")
    if name is not None and not isinstance(name, str):
        raise PathError(f"{fn}: name must be a string, got {name!r}")
    return CameraPath(times, np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                      np.array([r[2] for r in rows]), np.array([r[3] for r in rows], float),
                      int(frames), float(fps), res, fn, name)


def _num(val, what: str, fn: str) -> float:
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
        raise PathError(f"{fn}: {what} must be a finite number, got {val!r}")
    return float(val)


def _fov(val, what: str, fn: str) -> float:
    v = _num(val, what, fn)
    if not 0 < v < 180:
        raise PathError(f"{fn}: {what} must be in (0, 180) degrees, got {val!r}")
    return v


def _vec(val, what: str, fn: str) -> np.ndarray:
    if (not isinstance(val, list) or len(val) != 3
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in val)
            or not all(math.isfinite(x) for x in val)):
        raise PathError(f"{fn}: {what} must be a list of 3 finite numbers, got {val!r}")
    return np.array(val, float)


# ----------------------------------------------------------------------------- frames and video

@dataclass(frozen=True)
class Walkthrough:
    """A rendered walkthrough: its folder (frame PNGs, walkthrough.json), the video file, the
    number of frames, and its figures."""

    folder: str
    video: str
    frames: int
    figures: dict


def check_output(out: str) -> str:
    """The output format of `out` by its extension ("video" or "animated"), or PathError."""
    ext = os.path.splitext(out)[1].lower()
    if ext in VIDEO:
        return "video"
    if ext in ANIMATED:
        return "animated"
    raise PathError(f"--out {out}: give a file ending in one of "
                    f"{', '.join(VIDEO + ANIMATED)}")


class VideoWriter:
    """Frames (H, W, 3) uint8 appended one by one: an ffmpeg stream for .mp4/.mkv/.mov/.avi
    (H.264, yuv420p; imageio-ffmpeg's own ffmpeg binary), kept in memory and written at close
    by Pillow for .gif and .webp (looping)."""

    def __init__(self, out: str, fps: float):
        self.out, self.fps, self.kind = out, float(fps), check_output(out)
        self.tmp = os.path.join(os.path.dirname(out) or ".",
                                f".{os.path.basename(out)}.{os.getpid()}.tmp"
                                + os.path.splitext(out)[1])
        self.frames: list = []
        self.n = 0
        self._w = None

    def append(self, frame: np.ndarray) -> None:
        if self.kind == "video":
            if self._w is None:
                try:
                    import imageio_ffmpeg  # noqa: F401
                except ImportError:
                    raise RadiosityError("writing MP4 needs imageio-ffmpeg: pip install "
                                         "imageio-ffmpeg (or give --out FILE.gif / .webp)") from None
                import imageio

                # even sizes: yuv420p halves both; macro_block_size 2 pads an odd side by one
                self._w = imageio.get_writer(self.tmp, format="FFMPEG", mode="I", fps=self.fps,
                                             codec="libx264", quality=8, macro_block_size=2,
                                             ffmpeg_log_level="error")
            self._w.append_data(np.ascontiguousarray(frame))
        else:
            self.frames.append(np.ascontiguousarray(frame))
        self.n += 1

    def close(self) -> None:
        if self.kind == "video":
            if self._w is not None:
                self._w.close()
        elif self.frames:
            import imageio.v3 as iio

            kw = {"lossless": False, "quality": 90} if self.out.lower().endswith(".webp") else {}
            iio.imwrite(self.tmp, np.stack(self.frames), extension=os.path.splitext(self.out)[1],
                        duration=1000.0 / self.fps, loop=0, **kw)
        if self.n:
            os.replace(self.tmp, self.out)

    def discard(self) -> None:
        try:
            if self._w is not None:
                self._w.close()
        except Exception:
            pass
        if os.path.exists(self.tmp):
            os.remove(self.tmp)


def render_walkthrough(run_dir: str, path, out: str | None = None, name: str | None = None,
                       *, settings, samples: int | None = None, exposure: float | None = None,
                       progress: bool = True, keep_frames: bool = True, viewer=None,
                       on_frame=None) -> Walkthrough:
    """Render the camera path `path` (a CameraPath, or a TOML file for load_path) through the
    solved run `run_dir`: every frame a view of its solution (stages/views.Viewer, opened once
    for all frames), the frames as RUN/walkthroughs/NAME/frame-0001.png ... (keep_frames), the
    video into `out` (default RUN/walkthroughs/NAME/NAME.mp4; .mp4/.mkv/.mov/.avi, .gif or
    .webp), walkthrough.json beside the frames and a "walkthroughs" entry in report.json.
    NAME: `name`, else the path's `name`, else the path file's stem. samples: rays per pixel
    side (default views.VIEW_SAMPLES); exposure None: the run's. viewer: an open Viewer of
    run_dir to reuse; on_frame(k, image (H, W, 3) float64 linear, figures): called per frame."""
    from radiosity.runtime.monitor import progress_bar
    from radiosity.runtime.store import update_report
    from radiosity.core.colour import tonemap
    from radiosity.formats.images import write_png
    from radiosity.stages.views import VIEW_SAMPLES, Viewer, view_name

    t0 = time.perf_counter()
    if not isinstance(path, CameraPath):
        path = load_path(path)
    if name is None:
        name = path.name or (os.path.splitext(os.path.basename(path.source))[0]
                             if os.path.isfile(path.source) else "walkthrough")
    name = view_name(name, run_dir)
    folder = os.path.join(run_dir, "walkthroughs", name)
    if out is None:
        out = os.path.join(folder, f"{name}.mp4")
    check_output(out)
    samples = VIEW_SAMPLES if samples is None else int(samples)
    v = viewer if viewer is not None else Viewer(run_dir, settings)
    cams = path.cameras(v.store.load_camera())
    if exposure is None:
        exposure = v.exposure
    os.makedirs(folder, exist_ok=True)
    if os.path.dirname(out):
        os.makedirs(os.path.dirname(out), exist_ok=True)
    writer = VideoWriter(out, path.fps)
    per_frame, gathered = [], 0
    bar = progress_bar(len(cams), f"walkthrough {name}", progress, unit="frame")
    try:
        for k, cam in enumerate(cams):
            img, fig = v.image(cam, samples)
            if exposure is None:  # a run without a recorded exposure: the first frame's
                from radiosity.core.colour import auto_exposure

                exposure = auto_exposure(img)
            img8 = tonemap(img, exposure)
            if keep_frames:
                write_png(os.path.join(folder, f"frame-{k + 1:04d}.png"), img8)
            writer.append(img8)
            per_frame.append(fig["time_s"])
            gathered += int(fig["gather"].get("gathered_points", 0))
            if on_frame is not None:
                on_frame(k, img, fig)
            bar.update(1)
            bar.set_postfix(s_per_frame=f"{np.mean(per_frame):.2f}")
        writer.close()
    except BaseException:
        writer.discard()
        raise
    finally:
        bar.close()
    total = time.perf_counter() - t0
    figures = {"frames": len(cams), "fps": path.fps,
               "resolution": [cams[0].width, cams[0].height], "samples_per_pixel": samples ** 2,
               "method": v.method.name, "exposure": exposure, "video": os.path.abspath(out),
               "path": path.source, "interpolation": "cubic Hermite, Catmull-Rom tangents",
               "keyframes": {"time": path.times.tolist(), "position": path.position.tolist(),
                             "look_at": path.look_at.tolist()},
               "time_open_s": v.time_open_s if viewer is None else 0.0,
               "time_frames_s": round(float(np.sum(per_frame)), 4),
               "time_per_frame_s": round(float(np.mean(per_frame)), 4),
               "gathered_points": gathered, "time_s": round(total, 4)}
    with open(os.path.join(folder, "walkthrough.json"), "w") as f:
        json.dump(figures, f, indent=1)
    update_report(run_dir, "walkthroughs", {name: {
        k: figures[k] for k in ("frames", "time_s", "time_per_frame_s", "video")}})
    return Walkthrough(folder, out, len(cams), figures)
