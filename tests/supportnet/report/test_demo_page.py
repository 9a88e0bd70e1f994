"""The demo's report from small fake inputs: one document rendered as Markdown and as one
self-contained HTML page, every figure linked and present, colour bars on maps, captions naming
only colours their pictures have, and a sentence for every surprising number."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from calib.data.io import read_image
from calib.projection import ProjectedScan
from calib.support.class_residuals import ClassStats
from supportnet.report.demo_page import (
    SceneCheck,
    WorldRun,
    build_demo_page,
    caption_colour_problems,
    class_chart_figure,
    drive_speed,
    projection_figure,
    support_figure,
    write_demo_page,
)
from supportnet.report.document import plain_text, to_markdown
from supportnet.report.pictures import colour_bar_height, named_colours

H, W = 60, 160


def _image(seed: int = 0) -> np.ndarray:
    """A grey image (noise of one channel, repeated): no colour of its own."""
    rng = np.random.default_rng(seed)
    return np.repeat(np.clip(rng.normal(128, 20, (H, W, 1)), 0, 255).astype(np.uint8), 3, axis=2)


def _scan(depths: np.ndarray, seed: int = 0) -> ProjectedScan:
    rng = np.random.default_rng(seed)
    n = len(depths)
    uv = np.column_stack([rng.uniform(2, W - 3, n), rng.uniform(2, H - 3, n)])
    return ProjectedScan(np.arange(n), uv, depths.astype(float), np.zeros(n), (H, W))


def _error(t: float, r: float) -> dict:
    return {
        "translation_cm": t,
        "rotation_deg": r,
        "translation_xyz_cm": [t / 2, t / 4, t],
        "rotation_xyz_deg": [r, 0, 0],
    }


def _runs(ts: list[float], rs: list[float], correspondences: int = 900) -> dict:
    runs = [
        {
            "run": k,
            "T_cam_lidar": np.eye(4).tolist(),
            "initial_T_cam_lidar": np.eye(4).tolist(),
            "error": _error(t, r),
            "initial_error": _error(10.0, 2.0),
            "frame_indices": [0, 5],
            "correspondences": correspondences,
        }
        for k, (t, r) in enumerate(zip(ts, rs, strict=True))
    ]
    summary = {
        key: {"mean": float(np.mean(v)), "median": float(np.median(v)), "std": float(np.std(v))}
        for key, v in (("translation_cm", ts), ("rotation_deg", rs))
    }
    return {"runs": runs, "summary": summary, "correspondences": correspondences}


def _classes() -> dict:
    stats = [
        ClassStats("building", 5000, 0.4, 0.3, 0.35, 0.25, 0.5, 20.0, 0.8),
        ClassStats("road", 3000, 1.0, 0.5, 0.9, 0.4, 1.0, 7.0, 0.3),
        ClassStats("vegetation", 800, 2.5, 0.8, 2.3, 0.5, 2.6, 3.0, 0.1),
    ]
    return {
        "frames": 4,
        "matcher": "edge",
        "min_points_ranked": 50,
        "classes": {"all": [s.__dict__ for s in stats]},
    }, stats


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """A page from two fake worlds (SGIS wins on one, loses on the other; Stage 1 refuses on one
    and uses its prior on the other) and two fake scenes, written to a folder."""
    root = tmp_path_factory.mktemp("demo")
    classes, stats = _classes()
    near_far = np.concatenate([np.full(300, 2.0), np.full(300, 38.0)])
    worlds = []
    for world, sgis, sgis_r in (("vineyard", [2.0, 2.2], [0.2, 0.3]), ("urban", [4.0, 4.6], [0.25, 0.5])):
        run = WorldRun(
            world,
            world,
            "09",
            9,
            4,
            {"refused": "only 0 of 15 motion pairs rotate 1.0° or more (at least 3 needed): no rotation."}
            if world == "vineyard"
            else {
                "translation_source": "prior",
                "error": _error(30.0, 0.8),
                "hand_eye_error": _error(600.0, 0.8),
                "motions_used": 12,
                "config": {"translation_prior_m": [0.0, 0.0, 0.0]},
                "weak": [{"text": "translation along LiDAR +z (std 97 cm)"}],
            },
            {
                "results": {
                    "uniform": _runs([3.0, 3.2], [0.3, 0.35]),
                    "offline:maps": _runs(sgis, sgis_r, correspondences=700),
                },
                "paired_vs_uniform": {
                    "offline:maps": {
                        "runs": 2,
                        "translation_wins": int(sum(a < b for a, b in zip(sgis, [3.0, 3.2], strict=True))),
                        "rotation_wins": 1,
                    }
                },
            },
            classes,
            map_agreement=0.6,
        )
        run.figures["classes"] = class_chart_figure(
            root, f"figures/{world}_classes.png", stats, f"synthetic {world}", "Residuals by class."
        )
        run.figures["support:offline:maps"] = support_figure(
            root, f"figures/{world}_support.png", _image(), np.linspace(0, 1, H * W).reshape(H, W), "Map."
        )
        run.figures["overlay:uniform"] = projection_figure(
            root,
            f"figures/{world}_overlay.png",
            [("before", _image(1), _scan(near_far)), ("after", _image(2), _scan(near_far, 1))],
            "Before and after.",
        )
        worlds.append(run)
    scenes = [
        SceneCheck(
            "kitti-raw 0000000034",
            {"contour_points": 900, "reference": 0.5, "perturbed_mean": 0.3, "ratio": 1.7},
        ),
        SceneCheck(
            "pjlab 1", {"contour_points": 400, "reference": 0.4, "perturbed_mean": 0.35, "ratio": 1.14}
        ),
    ]
    doc = build_demo_page(worlds, scenes, runs=2, seconds=12.0, realdata="/data/realdata")
    md, html = write_demo_page(doc, root)
    return root, doc, md.read_text(), html.read_text()


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.attrs: list[tuple[str, str, str]] = []
        self.headings: list[str] = []
        self._in: str | None = None

    def handle_starttag(self, tag, attrs):
        self.attrs += [(tag, k, v or "") for k, v in attrs]
        if re.fullmatch(r"h[1-6]", tag):
            self._in, self._text = tag, ""

    def handle_data(self, data):
        if self._in:
            self._text += data

    def handle_endtag(self, tag):
        if tag == self._in:
            self.headings.append(self._text.strip())
            self._in = None


def test_html_is_self_contained(page):
    root, doc, _, html = page
    tags = _Tags()
    tags.feed(html)
    sources = [v for _, k, v in tags.attrs if k == "src"]
    assert len(sources) == len(doc.figures()) > 0
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    links = [v for _, k, v in tags.attrs if k in ("href", "src") and not v.startswith("data:")]
    assert all(v.startswith(("#", "http://", "https://")) for v in links), links
    assert not [v for v in links if re.search(r"\.(png|jpe?g|svg|gif)$", v, re.I)]
    assert "<link" not in html and "@import" not in html and "url(" not in html
    # the page holds no path of the figure files as a resource: moving it alone keeps it whole
    moved = root.parent / "moved.html"
    moved.write_text(html)
    assert moved.stat().st_size > sum((root / f.path).stat().st_size for f in doc.figures())


def test_every_png_of_the_markdown_exists_and_is_linked(page):
    root, doc, md, _ = page
    images = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", md)
    links = re.findall(r"(?<!!)\[[^\]]*\]\(([^)]+\.png)\)", md)
    assert sorted(set(images)) == sorted(f.path for f in doc.figures())
    assert all((root / p).is_file() for p in images)
    assert set(images) <= set(links)  # each image is also a link to its PNG


def test_markdown_and_html_carry_the_same_sections(page):
    _, doc, md, html = page
    md_headings = [plain_text(line.lstrip("#").strip()) for line in md.splitlines() if line.startswith("#")]
    tags = _Tags()
    tags.feed(html)
    assert md_headings == tags.headings
    assert len(md_headings) == len(doc.walk()) + 1
    assert "data all" not in md


def test_captions_name_only_colours_in_their_pictures(page):
    root, doc, _, _ = page
    assert caption_colour_problems(root, doc.figures()) == []
    overlay = next(f for f in doc.figures() if f.path.endswith("urban_overlay.png"))
    # 2 m is blue in turbo, 38 m red: both named, both there
    assert "mostly blue" in overlay.caption and "mostly red" in overlay.caption


def test_a_caption_naming_a_missing_colour_is_caught(tmp_path):
    figure = projection_figure(
        tmp_path, "p.png", [("x", _image(), _scan(np.full(200, 2.0)))], "Near points only."
    )
    figure.caption += " Far points are yellow."
    assert caption_colour_problems(tmp_path, [figure]) == [
        "p.png: caption names ['yellow'], not in the picture"
    ]


def test_maps_and_projections_carry_a_colour_bar(page):
    root, _, _, _ = page
    support = read_image(root / "figures/urban_support.png")
    bar = colour_bar_height(W)
    assert support.shape == (2 * H + bar, W, 3)  # image, map, then the bar strip
    strip = support[-bar:]
    assert {"purple", "yellow", "green", "black"} <= named_colours(strip, min_pixels=3)
    overlay = read_image(root / "figures/urban_overlay.png")
    assert overlay.shape == (2 * H + bar, W, 3)
    assert {"purple", "red", "green"} <= named_colours(overlay[-bar:], min_pixels=3)


def test_surprising_numbers_are_commented(page):
    _, _, md, _ = page
    assert (
        "**On urban, SGIS, offline map ended worse than uniform sampling** in mean translation error, "
        "4.30 cm against 3.10 cm, and rotation error, 0.375° against 0.325°; it had the smaller "
        "translation error in 0 of 2 paired runs" in md
    )
    assert "On vineyard, SGIS, offline map beat uniform sampling: mean translation error 2.10 cm" in md
    assert "Likely reason:" in md
    assert "puts 8" in md  # the building class takes most of the map's weight (a share computed from it)
    assert "**Stage 1 refused** on vineyard: only 0 of 15 motion pairs" in md
    assert "prior (not estimated)" in md and "30.0 cm" in md and "600.0 cm" in md
    assert "Vegetation has the largest mean |Δu|, 2.50 px" in md
    assert "smallest margin is pjlab 1 (ratio 1.14" in md


def test_conventions_cover_every_layout(page):
    _, _, md, _ = page
    for layout, rule in (
        ("KITTI odometry", "offset(P2) · Tr"),
        ("KITTI raw", "offset(P_rect_0X) · R_rect_00 · [R T]"),
        ("KITTI object", "offset(P2) · R0_rect · Tr_velo_to_cam"),
        ("custom folder", "`T_cam_lidar` as written"),
        ("ROS 1 / ROS 2 bag", "/tf_static"),
    ):
        row = next(line for line in md.splitlines() if line.startswith(f"| {layout} "))
        assert rule in row
    assert "kitti-raw 0000000034 (ratio 1.70)" in md
    bag = next(line for line in md.splitlines() if line.startswith("| ROS 1"))
    assert "not checked on real data" in bag


@pytest.mark.slow
def test_the_demo_writes_a_whole_page(tmp_path):
    """The real demo, small: both pages, every figure, and no caption naming a missing colour."""
    from supportnet.cli.cmd_demo import run_demo
    from supportnet.report.document import Figure

    out = tmp_path / "demo"
    run_demo(out, frames=8, runs=1)
    md = (out / "report.md").read_text()
    html = (out / "report.html").read_text()
    paths = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", md)
    assert paths and all((out / p).is_file() for p in paths)
    assert html.count('src="data:image/png;base64,') == len(paths)
    captions = re.findall(r"\*\*Figure \d+\.\*\* (.*) \(\[[^\]]+\]\(([^)]+)\)\)", md)
    figures = [Figure(path, caption) for caption, path in captions]
    assert len(figures) == len(paths)
    assert caption_colour_problems(out, figures) == []
    assert "data all" not in md
    assert Path(out / "figures").is_dir()


def test_a_translation_floor_and_a_large_stage1_rotation_are_commented():
    classes, _ = _classes()
    stage1 = {
        "translation_source": "prior",
        "error": _error(30.0, 6.9),
        "std_deg": [0.3, 0.4, 1.4],
        "reference_T_cam_lidar": [[1, 0, 0, 0.3], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        "config": {"translation_prior_m": [0.0, 0.0, 0.0]},
    }
    stage4 = {"results": {"uniform": _runs([6.5, 6.7], [0.2, 0.2]), "onnx": _runs([6.3, 6.5], [0.2, 0.2])}}
    for run in (r for x in stage4["results"].values() for r in x["runs"]):
        run["std_cm"] = 0.1
    world = WorldRun("urban", "urban", "09", 9, 4, stage1, stage4, classes, map_agreement=0.13)
    md = to_markdown(build_demo_page([world], [], runs=2, seconds=1.0))
    assert (
        "Stage 4 removes only 34% to 36% of the initial translation error (from 10.0 cm to 6.4–6.6 cm" in md
    )
    assert "along camera z (forward)" in md and "at most 0.1 cm, so this is a bias" in md
    assert "A 6.9° rotation error is large" in md and "4.9× the largest standard deviation" in md
    assert "exactly how far the reference lever arm is from that prior (30.0 cm)" in md
    assert "Pearson r = 0.13" in md and "That is low" in md and "still beat uniform sampling" in md


def test_stage4_ending_worse_than_it_started_is_said_so():
    classes, _ = _classes()
    stage4 = {
        "results": {"uniform": _runs([98.0, 104.0], [5.0, 0.5]), "onnx": _runs([20.0, 88.0], [6.0, 0.8])}
    }
    for run in (r for x in stage4["results"].values() for r in x["runs"]):
        run["std_cm"] = 0.3
    world = WorldRun("vineyard", "vineyard", "09", 9, 4, {"refused": "no rotation: none"}, stage4, classes)
    md = to_markdown(build_demo_page([world], [], runs=2, seconds=1.0))
    assert (
        "**On vineyard, Stage 4 made the translation worse** with every support: the mean error went "
        "from 10.0 cm to 54.0–101.0 cm (rotation from 2.00° to 2.75–3.40°)" in md
    )
    assert "likely a false minimum" in md and "removes only" not in md


def test_a_held_time_offset_away_from_the_worlds_is_named_as_the_floor():
    classes, _ = _classes()
    uniform = _runs([2.5, 2.6], [0.1, 0.1])
    uniform.update(
        time_offset_s=0.0,
        time_offset_std_s=None,
        time_offset_reference_s=0.02,
        time_offset_note="held at 0 s: the frames' motion varies too little (speed spread 0.05 m/s)",
    )
    stage4 = {"results": {"uniform": uniform, "onnx": _runs([2.9, 2.9], [0.3, 0.3])}}
    world = WorldRun("vineyard", "vineyard", "09", 9, 4, {"refused": "none"}, stage4, classes, speed_mps=1.2)
    md = to_markdown(build_demo_page([world], [], runs=2, seconds=1.0))
    assert (
        "the time offset δt was held at 0 ms while this world's camera fires 20 ms after the LiDAR; the "
        "frames' motion varies too little (speed spread 0.05 m/s). Each scan thus sits 20 ms of motion, "
        "2.4 cm at the drive's 1.2 m/s" in md
    )
    assert "(uniform sampling ends at 2.55 cm median)" in md
    uniform.update(time_offset_note="held at 0 s (time_offset.mode: fixed); points moved to it")
    md = to_markdown(build_demo_page([world], [], runs=2, seconds=1.0))
    assert "20 ms after the LiDAR; the config fixes it (time_offset.mode: fixed). Each scan" in md
    uniform.update(time_offset_s=0.0195, time_offset_std_s=0.0002)  # estimated: no floor to name
    md = to_markdown(build_demo_page([world], [], runs=2, seconds=1.0))
    assert "was held at" not in md


def test_drive_speed_is_the_median_step_over_its_time():
    poses = np.repeat(np.eye(4)[None], 4, axis=0)
    poses[:, 0, 3] = [0.0, 0.12, 0.24, 0.5]  # 1.2 m/s twice, then a 2.6 m/s outlier
    assert drive_speed(poses, np.array([0.0, 0.1, 0.2, 0.3])) == pytest.approx(1.2)
    assert drive_speed(None, np.zeros(4)) is None
    assert drive_speed(poses[:1], np.zeros(1)) is None
