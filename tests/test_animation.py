"""The impact movie: one streamed frame per snapshot, MP4 and GIF read back with imageio."""

from __future__ import annotations

import inspect
import logging
from pathlib import Path

import imageio
import imageio.v3 as iio
import numpy as np
import pytest

from emfabric.viz import animation, plots

from conftest import interrupted_demo, run_demo

TINY = {
    "fabric.nodes": [13, 13],
    "solver.end_time": 20e-6,
    "output.snapshot_interval": 5e-6,
    "fabric.damage.critical_stretch": 1.001,
    "fabric.damage.rate": 2.0,
}


def tiny_run(out: Path) -> Path:
    """Run the tiny scenario into ``out`` (the tests may use the simulator; animation may not)."""
    return run_demo(out, TINY)


@pytest.fixture(scope="session")
def movie_run(tmp_path_factory) -> Path:
    return tiny_run(tmp_path_factory.mktemp("movie"))


def snapshot_count(run_dir: Path) -> int:
    with plots.open_snapshots(run_dir) as s:
        return s.sizes["snapshot"]


def test_mp4_and_gif_have_one_frame_per_snapshot(movie_run):
    """animate writes impact.mp4 and impact.gif with as many frames as there are snapshots."""
    files = animation.animate(movie_run, gif=True, fps=5)
    figures = movie_run / "figures"
    assert files == [figures / "impact.mp4", figures / "impact.gif"]
    n = snapshot_count(movie_run)
    assert n >= 4
    with imageio.get_reader(files[0], format="FFMPEG") as reader:
        assert reader.count_frames() == n
        assert reader.get_meta_data()["size"] == animation.FRAME_SIZE
    gif = iio.improps(files[1], index=None)
    assert gif.shape[0] == n
    assert gif.shape[1:3] == (animation.FRAME_SIZE[1] // 2, animation.FRAME_SIZE[0] // 2)
    assert not list(figures.glob(".*partial*"))


def test_frames_are_rendered_one_at_a_time(movie_run):
    """render_frames is a generator yielding full-size RGB frames that change over the impact."""
    with plots.open_snapshots(movie_run) as s:
        frames = animation.render_frames(s)
        assert inspect.isgenerator(frames)
        first = next(frames)
        assert first.shape == (animation.FRAME_SIZE[1], animation.FRAME_SIZE[0], 3)
        assert first.dtype == np.uint8
        first = first.copy()
        rest = [frame[::8, ::8].copy() for frame in frames]
    assert len(rest) == s.sizes["snapshot"] - 1
    assert np.any(rest[-1] != first[::8, ::8])


def test_movie_colour_range_is_the_run_damage_range(movie_run):
    """The movie's colour range spans α over every snapshot of the run."""
    with plots.open_snapshots(movie_run) as s:
        alpha = s["yarn_damage"].values
        assert animation.damage_range_all(s) == (alpha.min(), alpha.max())


def test_partial_run_is_animated(tmp_path, caplog):
    """An interrupted run is animated as far as it got, with a warning that it is partial."""
    interrupted_demo(tmp_path, TINY, after=12)
    with caplog.at_level(logging.WARNING, logger="emfabric.viz.animation"):
        (mp4,) = animation.animate(tmp_path, fps=4)
    assert any("partial" in r.getMessage() for r in caplog.records)
    with imageio.get_reader(mp4, format="FFMPEG") as reader:
        assert reader.count_frames() == snapshot_count(tmp_path)


def test_failed_render_leaves_no_movie(movie_run, tmp_path, monkeypatch):
    """If rendering fails midway, neither the movie nor its temporary file is left behind."""
    run_dir = tmp_path / "copy"
    run_dir.mkdir()
    for name in ("history.nc", "snapshots.nc"):
        (run_dir / name).write_bytes((movie_run / name).read_bytes())

    def broken(snapshots, history=None, size=animation.FRAME_SIZE):
        yield np.zeros((size[1], size[0], 3), np.uint8)
        raise RuntimeError("boom")

    monkeypatch.setattr(animation, "render_frames", broken)
    with pytest.raises(RuntimeError, match="boom"):
        animation.animate(run_dir, gif=True)
    assert list((run_dir / "figures").iterdir()) == []


def test_without_ffmpeg_the_gif_still_works_and_mp4_says_what_to_install(movie_run, tmp_path,
                                                                         monkeypatch, caplog):
    """imageio-ffmpeg is an optional extra: without it an MP4 request names the extra, and a
    GIF is written by Pillow alone."""
    monkeypatch.setattr(animation, "mp4_available", lambda: False)
    with pytest.raises(RuntimeError, match=r"emfabric\[mp4\]"):
        animation.animate(movie_run)
    with caplog.at_level(logging.WARNING, logger="emfabric.viz.animation"):
        files = animation.animate(movie_run, gif=True)
    assert files == [movie_run / "figures" / "impact.gif"]
    assert any("emfabric[mp4]" in r.getMessage() for r in caplog.records)
    assert iio.improps(files[0], index=None).shape[0] == snapshot_count(movie_run)
