"""A movie of the impact from a run's snapshots: ``figures/impact.mp4`` (and ``impact.gif``).

Frames are rendered one at a time on a single Agg figure whose artists are updated in place,
and each frame goes straight to the encoders (ffmpeg from imageio-ffmpeg), so memory does not
grow with the number of snapshots. Reads ``snapshots.nc`` (and ``history.nc`` for the tilt and yaw)
only; never imports the simulator.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import imageio
import matplotlib
import numpy as np
import xarray as xr
from matplotlib.colors import Normalize

from emfabric.io.atomic import atomic_path
from emfabric.viz.plots import (
    STYLE,
    SectionView,
    SheetView,
    damage_colourbar,
    damage_range,
    has_projectile,
    new_figure,
    open_history,
    open_snapshots,
    ply_count,
    run_name,
    scene_limits,
    shown_segments,
    snapshot_tilt_deg,
    snapshot_yaw_deg,
    status_note,
    yarn_linewidth,
)

log = logging.getLogger(__name__)

FRAME_SIZE = (960, 720)
"""MP4 frame size [px] (width, height): multiples of 16, as H.264 wants. The GIF is half that."""


def damage_range_all(snapshots: xr.Dataset) -> tuple[float, float]:
    """Colour range of α over every snapshot of the run (the yarns drawn), read one snapshot at
    a time."""
    alpha = snapshots["yarn_damage"]
    shown = shown_segments(snapshots)
    lo = min(float(alpha[k].values[shown].min()) for k in range(alpha.shape[0]))
    hi = max(float(alpha[k].values[shown].max()) for k in range(alpha.shape[0]))
    return damage_range(np.array([lo, hi]))


def render_frames(snapshots: xr.Dataset, history: xr.Dataset | None = None,
                  size: tuple[int, int] = FRAME_SIZE) -> Iterator[np.ndarray]:
    """Yield one RGB frame (uint8, shape (height, width, 3)) per snapshot, rendered lazily.

    The colour range is the damage range over the whole run (fixed for the movie); the title
    carries the time, the tilt Θ and the yaw ψ, and the run's status when it did not
    complete. A pack of plies: the 3-D view is shortened and the plies' section
    (``SectionView``) runs under it.
    """
    count = snapshots.sizes["snapshot"]
    body = has_projectile(snapshots)
    meta = history if history is not None else snapshots
    name, note = run_name(meta), status_note(meta)
    norm = Normalize(*damage_range_all(snapshots))
    limits = scene_limits(snapshots, range(count))
    dpi = 100
    with matplotlib.rc_context(STYLE):
        fig = new_figure((size[0] / dpi, size[1] / dpi), layout=None)
        fig.set_dpi(dpi)
        section = None
        if ply_count(snapshots) > 1:
            ax = fig.add_axes((-0.06, 0.17, 0.9, 0.83), projection="3d")
            section = SectionView(fig.add_axes((0.08, 0.07, 0.68, 0.16)), snapshots)
        else:
            ax = fig.add_axes((-0.06, -0.06, 0.9, 1.0), projection="3d")
        view = SheetView(ax, snapshots, norm, limits,
                         linewidth=yarn_linewidth(snapshots, scale=1.3))
        damage_colourbar(fig, norm, fig.add_axes((0.81, 0.2, 0.02, 0.6)))
        title = fig.suptitle("")
    for k in range(count):
        t = float(snapshots["time"][k]) * 1e6
        text = (f"{name}    t = {t:7.2f} µs    tilt Θ = "
                f"{snapshot_tilt_deg(snapshots, k, history):6.2f}°")
        if body:
            text += f"    yaw ψ = {snapshot_yaw_deg(snapshots, k, history):6.2f}°"
        # the style is entered per frame, never held across a yield
        with matplotlib.rc_context(STYLE):
            view.update(snapshots, k)
            if section is not None:
                section.update(snapshots, k)
            title.set_text(text + (f"\n({note})" if note else ""))
            fig.canvas.draw()
        frame = np.asarray(fig.canvas.buffer_rgba())[..., :3]
        if frame.shape[:2] != (size[1], size[0]):
            raise RuntimeError(f"rendered {frame.shape[1]}x{frame.shape[0]} px, "
                               f"expected {size[0]}x{size[1]}")
        yield np.ascontiguousarray(frame)


class _Mp4Writer:
    """H.264 MP4 through imageio's ffmpeg plugin (the ffmpeg binary of the optional
    imageio-ffmpeg package), streamed frame by frame."""

    def __init__(self, path: Path, fps: int):
        self.path = path
        self._w = imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps,
                                     codec="libx264", quality=8, pixelformat="yuv420p",
                                     macro_block_size=16)

    def append(self, frame: np.ndarray) -> None:
        self._w.append_data(frame)

    def close(self) -> None:
        self._w.close()


class _GifWriter:
    """Looping GIF at half resolution with a palette per frame, by Pillow (no ffmpeg needed).

    Frames are kept as 8-bit palette images (a quarter of the pixels, one byte each) until
    close(), when Pillow writes the file."""

    def __init__(self, path: Path, fps: int, size: tuple[int, int]):
        self.path = path
        self.size = (size[0] // 2, size[1] // 2)
        self.duration_ms = 1000.0 / fps
        self._frames: list = []

    def append(self, frame: np.ndarray) -> None:
        from PIL import Image

        h, w = self.size[1], self.size[0]
        # 2 x 2 box average: half size without aliasing the thin yarn lines
        small = frame[: 2 * h, : 2 * w].reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
        image = Image.fromarray(np.ascontiguousarray(small.round().astype(np.uint8)))
        self._frames.append(image.quantize(colors=256, method=Image.Quantize.MEDIANCUT))

    def close(self) -> None:
        first, *rest = self._frames
        first.save(self.path, format="GIF", save_all=True, append_images=rest,
                   duration=self.duration_ms, loop=0, disposal=1)


def mp4_available() -> bool:
    """Whether the optional ffmpeg binary for MP4 (the `mp4` extra) is installed."""
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return False
    return True


MP4_MISSING = ("MP4 needs the ffmpeg binary of imageio-ffmpeg, an optional extra: "
               "pip install 'emfabric[mp4]'. GIFs (--gif) and figures work without it.")


def animate(run_dir: Path, gif: bool = False, fps: int = 10, mp4: bool = True) -> list[Path]:
    """Write ``RUN/figures/impact.mp4`` (and ``impact.gif``), one frame per snapshot.

    Returns the files written. A run that did not complete is animated as far as it got,
    with its status in the title.
    """
    run_dir = Path(run_dir)
    if fps < 1:
        raise ValueError(f"fps must be at least 1, got {fps}")
    if mp4 and not mp4_available():
        if not gif:
            raise RuntimeError(MP4_MISSING)
        log.warning("%s Writing the GIF only.", MP4_MISSING)
        mp4 = False
    history = open_history(run_dir) if (run_dir / "history.nc").is_file() else None
    out_dir = run_dir / "figures"
    with open_snapshots(run_dir) as snaps:
        note = status_note(history if history is not None else snaps)
        if note:
            log.warning("%s is not a complete run (%s); animating what it holds", run_dir, note)
        out_dir.mkdir(parents=True, exist_ok=True)
        with ExitStack() as stack:
            writers: list[_Mp4Writer | _GifWriter] = []
            # each movie is written under a hidden temporary name and renamed into place only
            # when it is complete (a failed render leaves nothing)
            if mp4:
                tmp = stack.enter_context(atomic_path(out_dir / "impact.mp4"))
                writers.append(_Mp4Writer(tmp, fps))
            if gif:
                tmp = stack.enter_context(atomic_path(out_dir / "impact.gif"))
                writers.append(_GifWriter(tmp, fps, FRAME_SIZE))
            try:
                for frame in render_frames(snaps, history, FRAME_SIZE):
                    for w in writers:
                        w.append(frame)
            finally:
                for w in writers:
                    w.close()
    return [p for p, on in ((out_dir / "impact.mp4", mp4), (out_dir / "impact.gif", gif)) if on]
