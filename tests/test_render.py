"""render/: the drawing style shared by `run --render` and `dataset show`, the H.264 video and
the HTML report. Object dicts are built here (with and without the tracker's ``track_id``);
one real `run --render --video --report` on the shipped sample proves the CLI path."""
from __future__ import annotations

import math
import re
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.dataset.groundtruth import ObjectTruth
from toffe_deploy.render import draw
from toffe_deploy.render.frames import FrameRenderer
from toffe_deploy.render.report import RunReport
from toffe_deploy.render.truth import TruthShapes
from toffe_deploy.render.video import FrameSink, video_info
from toffe_deploy.runtime.spikes import SpikeVolume

SENSOR = (64, 48)
SAMPLE = Path(__file__).resolve().parent.parent / "toffe_deploy" / "samples" / "sample_multi.h5"


def hue_deg(bgr) -> int:
    return int(cv2.cvtColor(np.uint8([[bgr]]), cv2.COLOR_BGR2HSV)[0, 0, 0]) * 2


def luma(c) -> float:
    return 0.114 * c[..., 0] + 0.587 * c[..., 1] + 0.299 * c[..., 2]


def test_palette_hue_is_direction_and_readable_on_black_and_white():
    cols = draw.flow_color(np.radians([0.0, 90.0, 180.0, 270.0]))
    assert [hue_deg(c) for c in cols] == [0, 90, 180, 270]     # y down: 90 = moving down the image
    wheel = draw.flow_color(np.radians(np.arange(360))).astype(float)
    full = draw.flow_color(np.radians(np.arange(360)), saturation=1.0).astype(float)
    assert luma(full).min() < 30                               # full-saturation blue: invisible on black
    assert luma(wheel).min() > 90 and luma(wheel).max() < 240  # ours: visible on black; halo does white


def test_legend_wheel_angles_follow_the_y_down_convention():
    img = np.zeros((480, 640, 3), np.uint8)
    draw.draw_legend(img, draw.THEMES["dark"])
    ys, xs = np.nonzero(img.max(2) > 0)
    # find the wheel centre: the coloured disk's pixels are saturated
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    sat = np.argwhere(hsv[..., 1] > 150)
    cy, cx = sat.mean(0).round().astype(int)
    r = 20
    assert abs(hue_deg(img[cy, cx + r]) - 0) <= 4 or hue_deg(img[cy, cx + r]) >= 356
    assert abs(hue_deg(img[cy + r, cx]) - 90) <= 4       # below the centre: moving down = 90
    assert abs(hue_deg(img[cy - r, cx]) - 270) <= 4
    assert xs.max() < 640 and ys.max() < 480 and img[:200].max() == 0   # bottom-right corner only


def _volume(points, sensor=SENSOR):
    """A SpikeVolume with ON events at the given (x, y) pixels."""
    dense = np.zeros((1, 2, sensor[1], sensor[0]), bool)
    for x, y in points:
        dense[0, 1, y, x] = True
    return SpikeVolume.from_dense(dense)


def _obj(x, y, deg, track_id=None, speed_bin=2, speed=30.0):
    o = {"speed_bin": speed_bin, "ofs_bin": speed_bin, "speed_mps": speed, "speed_bin_mps": 30.0,
         "speed_px_s": 3000.0, "x": x, "y": y, "direction_rad": math.radians(deg), "n_events": 40,
         "direction_deg": deg}
    if track_id is not None:
        o["track_id"] = track_id
    return o


@pytest.mark.parametrize("tracked", [True, False])
def test_frames_draw_trails_by_track_id_and_degrade_without(tmp_path, tracked):
    r = FrameRenderer(tmp_path / ("t" if tracked else "u"))
    s = draw.frame_scale(SENSOR)
    path = [(10.0, 30.0), (20.0, 30.0), (30.0, 30.0)]
    for i, (x, y) in enumerate(path):
        frame = r.frame(_volume([(5, 5)]), {"t0_us": 500 * i, "objects": [_obj(x, y, 0.0, 7 if tracked else None)]})
    r.close(ok=False)
    assert frame.shape == (SENSOR[1] * s, SENSOR[0] * s, 3)
    mid = draw.to_px(15.0, 30.0, s)                            # on the trail between windows 0 and 1
    hsv = cv2.cvtColor(frame[mid[1] - 2:mid[1] + 3, mid[0] - 2:mid[0] + 3], cv2.COLOR_BGR2HSV).reshape(-1, 3)
    red = (hsv[:, 1] > 100) & ((hsv[:, 0] <= 5) | (hsv[:, 0] >= 175))   # hue 0: moving right
    assert red.any() == tracked
    ev = draw.to_px(5, 5, s)
    assert tuple(frame[ev[1], ev[0]]) == draw.THEMES["dark"].on


def test_frame_time_is_ms_into_a_recording_or_a_clock_time_for_epoch_timestamps():
    """A DV camera's epoch timestamps were labelled "t = 1700000000000005.1 ms"."""
    from toffe_deploy.render.frames import time_label

    assert time_label(5_100) == "5.1 ms" and time_label(3_600_000_000) == "3600000.0 ms"
    assert time_label(1_700_000_000_000_005) == "2023-11-14 22:13:20.000005 UTC"


def test_a_tentative_tracks_id_is_not_drawn():
    from toffe_deploy.render.draw import Mark

    o = _obj(10, 10, 0.0, track_id=5)
    assert Mark.of(o).label().startswith("#5 ")
    o["track"] = {"confirmed": False}
    assert Mark.of(o).track_id is None and not Mark.of(o).label().startswith("#")


def test_label_is_beside_the_object_not_over_it_nor_its_arrow():
    centre, tip = (100, 100), (160, 100)          # arrow to the right
    obj_box = (85, 85, 115, 115)
    x0, y0 = draw.place_label((50, 12), centre, 18, tip, [obj_box], (400, 300))
    box = (x0, y0, x0 + 50, y0 + 12)
    assert draw._overlap(box, obj_box) == 0 and draw._overlap(box, (100, 98, 160, 102)) == 0
    assert abs((x0 + 25) - centre[0]) < 80 and abs((y0 + 6) - centre[1]) < 40   # still beside it
    x1, _ = draw.place_label((50, 12), (390, 100), 18, None, [], (400, 300))
    assert x1 + 50 <= 400                                   # kept inside the frame


def test_truth_outlines_follow_shape_and_size_from_the_file_attrs():
    attrs = {"focal_px": 500.0, "objects": [{"shape": "square", "size_m": 0.4, "trajectory": {"depth_m": 5.0}},
                                            {"shape": "circle", "size_m": 0.2, "trajectory": {"depth_m": 4.0}}]}
    truths = [ObjectTruth(0, 100.0, 80.0, 0.0, 20.0, 2, 2.0, 5.0),      # depth column: 5 m -> r = 20 px
              ObjectTruth(1, 200.0, 80.0, math.pi / 2, 5.0, 1, None, None),   # mean depth 4 m -> 12.5 px
              ObjectTruth(5, 50.0, 50.0, 0.0, 5.0, 1)]                    # unknown object: nominal circle
    marks = TruthShapes(attrs).marks(truths)
    assert [(m.shape, m.radius_px) for m in marks] == [("square", 20.0), ("circle", 12.5), (None, None)]
    pts = draw.shape_outline("square", 100.0, 80.0, 20.0, margin=3.5)
    cheb = np.abs(pts - [100.0, 80.0]).max(1)
    assert np.all(np.abs(cheb - 23.5) <= 1.5)               # the square grown by the margin
    img = np.zeros((200, 300, 3), np.uint8)
    draw.draw_truth(img, marks, 1, 10.0, draw.THEMES["dark"], labels=True, taken=[])
    colour = tuple(int(v) for v in draw.flow_color(0.0))
    right_side = {tuple(int(v) for v in img[80 + dy, x]) for dy in range(-20, 21) for x in (122, 123, 124, 125)}
    assert colour in right_side                             # the dashed outline, in the direction's colour
    assert not img[62:70, 105:118].any()                    # inside the outline, off its arrow: nothing drawn


@pytest.mark.parametrize("size", [(64, 48), (65, 47)])
def test_h264_video_plays_in_browsers(tmp_path, size):
    sink = FrameSink(tmp_path / "v", video=True, fps=25)
    for i in range(5):
        f = np.zeros((size[1], size[0], 3), np.uint8)
        f[:, i * 5:i * 5 + 8] = (40, 200, 255)
        sink.add(f)
    sink.close(ok=True)
    out = tmp_path / "v" / "object_flow.mp4"
    assert video_info(out) == ("h264", "yuv420p", 5)
    data = out.read_bytes()
    assert b"avc1" in data[:64] or b"avc1" in data               # H.264 sample entry, browsers' codec
    assert data.index(b"moov") < data.index(b"mdat")              # faststart: index before the data
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["object_flow.mp4"]


def test_failed_run_leaves_no_frames(tmp_path):
    sink = FrameSink(tmp_path / "gone", video=True)
    sink.add(np.zeros((48, 64, 3), np.uint8))
    sink.close(ok=False)
    assert not (tmp_path / "gone").exists()


def test_a_shorter_run_into_the_same_directory_leaves_only_its_frames(tmp_path):
    """DIR holds one run's frames: a 2-frame run after a 4-frame one removes frames 2 and 3,
    and nothing else (a file of the user's stays)."""
    frame = np.zeros((48, 64, 3), np.uint8)
    for n in (4, 2):
        sink = FrameSink(tmp_path / "r")
        for _ in range(n):
            sink.add(frame)
        sink.close(ok=True)
        if n == 4:
            (tmp_path / "r" / "notes.txt").write_text("mine")
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["frame_000000.png", "frame_000001.png", "notes.txt"]


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids, self.text, self.urls, self.tags = set(), [], [], set()

    def handle_starttag(self, tag, attrs):
        self.tags.add(tag)
        for k, v in attrs:
            if k == "id":
                self.ids.add(v)
            if k in ("src", "href") and v:
                self.urls.append(v)

    def handle_data(self, data):
        self.text.append(data)


def _parse(path):
    page = _Page()
    raw = Path(path).read_text(encoding="utf-8")
    page.feed(raw)
    return page, " ".join(page.text), raw


def test_report_sections_numbers_and_no_urls(tmp_path):
    rep = RunReport(SENSOR, source="test")
    for i in range(6):
        objs = [_obj(10 + 3 * i, 20, 0.0, track_id=1, speed_bin=2, speed=30.0 + i)]
        if i >= 3:
            objs.append(_obj(50, 40 - 2 * i, 270.0, track_id=4, speed_bin=4, speed=120.0))
        rep.add({"t0_us": 500 * i, "t1_us": 500 * i + 500, "objects": objs})
    summary = {"target": "cpu", "windows": 6, "objects": 9, "wall_s": 0.25, "windows_per_s": 24.0,
               "realtime_factor": 0.012, "startup_s": 1.5, "latency_ms": {"p50": 3.25, "p90": 7.5, "p99": 9.0},
               "objects_per_bin": {"2": 6, "4": 3}, "errors": None, "camera": {"focal_px": 554.3, "depth_m": 5.0}}
    rep.write(tmp_path / "r.html", summary)
    page, text, raw = _parse(tmp_path / "r.html")
    assert {"summary", "bins", "tracks", "speed"} <= page.ids and "svg" in page.tags
    assert not re.search(r"https?://", raw) and not page.urls          # self-contained
    assert "24" in text and "3.25" in text and "0.012" in text         # summary figures
    assert re.search(r"bin 2\s+6\s+66\.7%\s+1", text) and re.search(r"bin 4\s+3\s+33\.3%\s+1", text)
    assert "#1" in text and "#4" in text and "no track ids" not in text
    rep3 = RunReport(SENSOR)                 # a tentative track's provisional id is no track of the page
    for i in range(3):
        o = _obj(10 + i, 10, 0.0, track_id=7 if i else 9)
        o["track"] = {"confirmed": bool(i)}
        rep3.add({"t0_us": 500 * i, "t1_us": 500 * i + 500, "objects": [o]})
    rep3.write(tmp_path / "t.html", summary)
    t3 = _parse(tmp_path / "t.html")[1]
    assert "#7" in t3 and "#9" not in t3 and "no track ids" not in t3
    rep2 = RunReport(SENSOR)
    rep2.add({"t0_us": 0, "t1_us": 500, "objects": [_obj(10, 10, 90.0)]})
    rep2.write(tmp_path / "u.html", summary)
    from toffe_deploy.runtime.output import RunSummary

    sim = RunSummary(target="loihi-sim", tag="fixed_pt", latencies_s=[1.2, 1.3]).to_json()
    assert sim["latency_kind"] == "simulator wall time per window (not Loihi 2 latency)" and sim["tag"] == "fixed_pt"
    sim["bridge_traffic"] = {"windows": 2, "per_window": {"to_chip_spikes": 1950.0}}
    rep.write(tmp_path / "s.html", sim)
    sim_text = _parse(tmp_path / "s.html")[1]
    assert "simulator wall time per window (not Loihi 2 latency), p50 (ms)" in sim_text and "fixed_pt" in sim_text
    assert "bridge per window: to chip spikes" in sim_text and "1,950" in sim_text
    rep.write(tmp_path / "c.html", RunSummary(target="cpu", tag="fixed_pt", latencies_s=[1e-3]).to_json())
    assert "Lava process models" in sim_text and "Lava process models" not in _parse(tmp_path / "c.html")[1]
    untracked = _parse(tmp_path / "u.html")[1]
    assert "no track ids" in untracked and "One lane per speed bin" in untracked and "One lane per track" not in untracked
    assert "One lane per track" in text


def test_run_render_video_and_report_on_the_shipped_sample(tmp_path, make_bundle, capsys):
    bundle = make_bundle(tmp_path)
    rc = main(["run", str(bundle.root), "--target", "cpu", "--max-windows", "3", "--render", str(tmp_path / "r"),
               "--video", "--report", str(tmp_path / "rep.html"), "--out", str(tmp_path / "o.jsonl"),
               "--no-progress"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert video_info(tmp_path / "r" / "object_flow.mp4") == ("h264", "yuv420p", 3)
    page, text, raw = _parse(tmp_path / "rep.html")
    assert {"summary", "bins", "tracks", "speed"} <= page.ids and not re.search(r"https?://", raw)
    assert re.search(r"windows\s+3\b", text) and "recall vs ground truth" in text   # the sample has truth
    # the same run as PNG: the sample's ground truth drawn as outlines (4 objects, coloured dashes)
    rc = main(["run", str(bundle.root), "--max-windows", "1", "--render", str(tmp_path / "p"), "--out",
               str(tmp_path / "o2.jsonl"), "--no-progress"])
    assert rc == 0
    img = cv2.imread(str(tmp_path / "p" / "frame_000000.png"))
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    assert (hsv[:300, ..., 1] > 100).sum() > 4 * 40           # coloured outlines / arrows, above the legend


def test_report_refused_onto_an_input(tmp_path, make_bundle, capsys):
    bundle = make_bundle(tmp_path)
    rc = main(["run", str(bundle.root), "--report", str(bundle.root / "manifest.json"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "--report would overwrite" in err and err.count("\n") == 1


@pytest.mark.parametrize("fps", ["0", "nan", "inf"])
def test_bad_fps_is_one_line_error_and_leaves_nothing(tmp_path, make_bundle, capsys, fps):
    bundle = make_bundle(tmp_path)
    rc = main(["run", str(bundle.root), "--render", str(tmp_path / "v"), "--video", "--fps", fps, "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "--fps must be in" in err and err.count("\n") == 1
    assert not (tmp_path / "v").exists()


def test_frames_wider_than_png_takes_are_refused_before_the_run(tmp_path, make_bundle, capsys):
    """A 65000x1 sensor draws 1,040,000 px wide frames (x16), past libpng's limit: it refused them
    with lines of its own and ours blamed the OpenCV build; now one line before any window."""
    from toffe_deploy.events.io import write_events_npz

    bundle = make_bundle(tmp_path)
    ev = np.zeros(3, [("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])
    ev["x"], ev["t"] = [10, 20, 30], [0, 1000, 2000]
    write_events_npz(tmp_path / "wide.npz", ev, (65000, 1))
    rc = main(["run", str(bundle.root), "--events", str(tmp_path / "wide.npz"), "--render", str(tmp_path / "v"),
               "--out", str(tmp_path / "o.jsonl"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "draws 1,040,000x16 px frames, more than PNG takes" in err
    assert not (tmp_path / "v").exists() and not (tmp_path / "o.jsonl").exists()


def test_fps_without_video_is_refused(tmp_path, make_bundle, capsys):
    bundle = make_bundle(tmp_path)
    rc = main(["run", str(bundle.root), "--render", str(tmp_path / "v"), "--fps", "-3", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "--fps sets the --video file's frame rate" in err and err.count("\n") == 1
    assert not (tmp_path / "v").exists()


def test_theme_without_render_is_refused(tmp_path, make_bundle, capsys):
    """--theme only colours --render's frames: alone it would be ignored, so it is refused as --fps is."""
    bundle = make_bundle(tmp_path)
    rc = main(["run", str(bundle.root), "--theme", "light", "--out", str(tmp_path / "o.jsonl"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "--theme sets the --render frames' background" in err and err.count("\n") == 1
    assert not (tmp_path / "o.jsonl").exists()


def test_untracked_report_counts_windows_not_detections_and_names_its_series(tmp_path):
    rep = RunReport(SENSOR)
    for i in range(3):                       # two bin-2 objects a window: 6 detections in 3 windows
        rep.add({"t0_us": 500 * i, "t1_us": 500 * i + 500,
                 "objects": [_obj(10 + i, 10, 0.0, speed_bin=2), _obj(40 + i, 30, 0.0, speed_bin=2)]})
    rep.write(tmp_path / "u.html", {"target": "cpu", "windows": 3, "objects": 6})
    text = _parse(tmp_path / "u.html")[1]
    assert re.search(r"bin 2\s+0\.0\s+1\.0\s+3\s+bin 2", text)       # series, first, last (ms), windows 3, not 6
    assert "Speed per speed bin" in text and "Speed per track" not in text


@pytest.mark.parametrize("size, scale", [((640, 480), 1), ((346, 260), 2), ((320, 240), 2), ((64, 48), 8),
                                         ((1280, 720), 1)])
def test_small_sensors_are_drawn_at_least_360_px_on_the_shorter_side(size, scale):
    assert draw.frame_scale(size) == scale and min(size) * scale >= min(360, min(size))


def test_a_faint_object_is_a_grey_ring_without_arrow_or_speed():
    """ofpd.faint_objects: the position is measured, the direction a guess: no arrow, no hue."""
    o = _obj(100, 100, 0.0, track_id=3, speed_bin=1)
    plain = draw.compose(np.zeros((200, 300, 3), np.uint8), [draw.Mark.of(o)], scale=1, unit=20.0,
                         theme=draw.theme_of("dark"), legend=False)
    o["faint"] = True
    m = draw.Mark.of(o)
    assert m.faint and m.label() == "#3 faint"
    trails = draw.Trails()
    for x in (80.0, 90.0):                           # two windows before, faint too: a grey trail
        trails.update([draw.Mark(x, 100.0, 0.0, 1, None, 3, True)])
    img = draw.compose(np.zeros((200, 300, 3), np.uint8), [m], scale=1, unit=20.0,
                       theme=draw.theme_of("dark"), legend=False, trails=trails.update([m]))
    assert img[100, 81:85].max() >= 150                         # the trail is drawn
    hue = lambda im: int((im.max(axis=2).astype(int) - im.min(axis=2)).max())   # colour means direction
    assert hue(plain) > 100 and hue(img) <= 2                   # no arrow, no direction colour anywhere
    assert img[100, 86:91].max() >= 150 and img[100, 109:114].max() >= 150   # the ring, 12 px each side
