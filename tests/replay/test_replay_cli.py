"""``smarts replay info`` and ``smarts replay show`` through the real command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from PIL import Image

from smarts.__main__ import main
from smarts.scenario.builtin_maps import builtin_map_path
from tests.replay.files import three_vehicles, write_ngsim


def test_info_json_reports_vehicles_duration_frames_and_extent(tmp_path, capsys):
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    assert main(["replay", "info", str(path), "--format", "ngsim", "--swap-xy", "--flip-y", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["vehicles"] == 3 and info["frames"] == 90 and abs(info["duration_s"] - 8.9) < 1e-9
    assert info["max_at_once"] == 3 and info["types"] == {"passenger": 2, "truck": 1}
    e = info["extent"]
    assert abs(e["xmin"] - 10.0) < 0.01 and abs(e["xmax"] - 115.2) < 0.01 and abs(e["ymin"] + 4.8) < 0.01


def test_info_table_and_errors_through_the_installed_command(tmp_path):
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    done = subprocess.run([sys.executable, "-m", "smarts", "replay", "info", str(path), "--format", "ngsim"],
                          capture_output=True, text=True, check=False)  # fmt: skip
    assert done.returncode == 0 and "vehicles" in done.stdout and "8.9 s" in done.stdout
    (tmp_path / "bad.csv").write_text("Vehicle_ID,Frame_ID\n1,2\n")
    done = subprocess.run([sys.executable, "-m", "smarts", "replay", "info", str(tmp_path / "bad.csv"), "--format",
                           "ngsim"], capture_output=True, text=True, check=False)  # fmt: skip
    assert done.returncode == 2 and "bad.csv" in done.stderr and "Local_X" in done.stderr
    assert "Traceback" not in done.stderr


def test_show_draws_the_vehicles_where_they_are(tmp_path, capsys):
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    out = tmp_path / "frame.png"
    net = builtin_map_path("straight_2lane")
    args = ["replay", "show", str(path), "--format", "ngsim", "--swap-xy", "--flip-y", "--time", "3.5",
            "--map", str(net), "--out", str(out), "--width", "620"]  # fmt: skip
    assert main(args) == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    # the canvas spans the map (x -1.6 .. 301.6 m) with 5 m margins in 620 pixels
    blue = np.abs(image - [80, 170, 255]).sum(axis=2) < 30
    cols = np.flatnonzero(blue.any(axis=0))
    xs = cols / (620 / 313.2) - 6.6
    # at 3.5 s: vehicle 1 at 55 m, vehicle 2 (12 m truck) at 40 m, vehicle 3 at 104 m
    for centre, length in ((55.0, 4.5), (40.0, 12.0), (104.0, 4.5)):
        inside = xs[(xs > centre - length / 2 - 1) & (xs < centre + length / 2 + 1)]
        assert inside.size >= 2 * length - 3, centre
    assert main(["replay", "show", str(path), "--format", "ngsim", "--out", str(tmp_path / "v.gif"), "--fps", "5"]) == 0
    gif = Image.open(tmp_path / "v.gif")
    assert gif.n_frames == 45  # 8.9 s at 5 frames per second
    assert main(["replay", "show", str(path), "--format", "ngsim", "--out", str(tmp_path / "v.mp4")]) == 0
    assert (tmp_path / "v.mp4").stat().st_size > 1000
    assert main(["replay", "show", str(path), "--format", "ngsim", "--out", str(tmp_path / "v.txt")]) == 2
    assert "expected a .png image" in capsys.readouterr().err


def test_show_draws_a_datasets_own_lanes(tmp_path, capsys):
    from tests.replay.files import write_av2, write_waymo

    folder = write_av2(tmp_path / "scn")
    out = tmp_path / "av2.png"
    assert main(["replay", "show", str(folder), "--format", "argoverse2", "--time", "3", "--out", str(out)]) == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    grey = (np.abs(image - [96, 100, 108]).sum(axis=2) < 10).sum()
    blue = (np.abs(image - [80, 170, 255]).sum(axis=2) < 30).sum()
    assert grey > 500 and blue > 50  # four 100 m lane centres and three vehicles
    tf = write_waymo(tmp_path / "s.tfrecord")
    assert main(["replay", "info", str(tf), "--format", "waymo", "--json"]) == 0
    info = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert info["vehicles"] == 3 and info["frames"] == 91 and info["map_lanes"] == 4


def _colour(image: np.ndarray, rgb, tolerance: int = 12) -> np.ndarray:
    return np.abs(image - np.array(rgb)).sum(axis=2) <= tolerance


def test_show_draws_edges_crosswalks_pedestrians_and_signal_states(tmp_path):
    from smarts.replay.render import CROSSWALK_FILL, CYCLIST, EDGE, EGO, PEDESTRIAN, SIGNAL_COLOURS, WHITE
    from tests.replay.files import waymo_junction, write_waymo

    tf = write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])
    images = {}
    for t in ("3.0", "6.0"):  # 201's signal is red at 3 s, green at 6 s
        out = tmp_path / f"j{t}.png"
        assert (
            main(["replay", "show", str(tf), "--format", "waymo", "--time", t, "--width", "1600", "--out", str(out)])
            == 0
        )
        images[t] = np.asarray(Image.open(out).convert("RGB")).astype(int)
    image = images["3.0"]
    # the map spans x -5 .. 335 m in 1600 pixels (the north road makes it tall)
    scale = 1600 / 340.0

    def column(x: float) -> int:
        return int(round((x + 5.0) * scale))

    assert _colour(image, EDGE).sum() > 500 and _colour(image, WHITE).sum() > 300  # road edges, painted lines
    assert _colour(image, CROSSWALK_FILL)[:, column(238.5) : column(241.5)].sum() > 20  # the crosswalk at x 240
    assert _colour(image, PEDESTRIAN)[:, column(239) : column(241)].sum() > 5  # the pedestrian on it
    assert _colour(image, CYCLIST).sum() > 5 and _colour(image, EGO).sum() > 50
    red, green = SIGNAL_COLOURS[1], SIGNAL_COLOURS[3]
    near_stop = slice(column(200), column(206))
    # at 3 s: 201 stop and 202 arrow stop are red, 203 go is green; at 6 s 201 has turned green
    assert _colour(image, red)[:, near_stop].sum() > 1.5 * _colour(images["6.0"], red)[:, near_stop].sum() > 0
    assert _colour(images["6.0"], green)[:, near_stop].sum() > 1.5 * _colour(image, green)[:, near_stop].sum() > 0


def test_show_draws_argoverse2_crossings_and_ngsim_map_edges(tmp_path):
    from smarts.replay.render import BIKE_FILL, CROSSWALK_FILL, EDGE, PEDESTRIAN
    from tests.replay.files import av2_map_with_crossings, write_av2

    folder = write_av2(tmp_path / "scn", map_data=av2_map_with_crossings())
    out = tmp_path / "av2.png"
    assert main(["replay", "show", str(folder), "--format", "argoverse2", "--time", "3", "--out", str(out)]) == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert _colour(image, CROSSWALK_FILL).sum() > 50 and _colour(image, BIKE_FILL).sum() > 500
    assert _colour(image, PEDESTRIAN).sum() > 3 and _colour(image, EDGE).sum() > 500
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    out = tmp_path / "ngsim.png"
    net = builtin_map_path("straight_2lane")
    assert main(["replay", "show", str(path), "--format", "ngsim", "--swap-xy", "--flip-y", "--map", str(net),
                 "--out", str(out)]) == 0  # fmt: skip
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    rows = np.flatnonzero(_colour(image, EDGE).sum(axis=1) > 300)  # the road's two outer edges, end to end
    assert len(rows) >= 2 and rows.max() - rows.min() > 10


def test_show_follows_the_ego_in_videos_with_a_hud_and_a_legend(tmp_path, capsys):
    from smarts.replay.render import EGO
    from tests.replay.files import waymo_junction, write_waymo

    path = write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])
    out = tmp_path / "v.gif"
    assert (
        main(["replay", "show", str(path), "--format", "waymo", "--out", str(out), "--duration", "2", "--fps", "5"])
        == 0
    )
    gif = Image.open(out)
    assert gif.size == (800, 560) and gif.n_frames == 11  # 800 x 500 of road at 6 px/m, HUD and legend bands
    top, view = 36, (800, 500)
    for k in range(gif.n_frames):
        gif.seek(k)
        frame = np.asarray(gif.convert("RGB")).astype(int)
        centre = frame[top + view[1] // 2 - 4 : top + view[1] // 2 + 4, view[0] // 2 - 10 : view[0] // 2 + 10]
        assert (np.abs(centre - EGO).sum(axis=2) < 40).sum() > 40, k  # the ego stays in the middle
        assert frame[:top].mean() < 40 and frame[:top].max() > 200  # the HUD: light text on a dark band
    # The whole recording instead, and a road user that is not there.
    assert main(["replay", "show", str(path), "--format", "waymo", "--out", str(tmp_path / "w.gif"), "--duration", "1",
                 "--follow", "none"]) == 0  # fmt: skip
    assert Image.open(tmp_path / "w.gif").size != (800, 560)
    capsys.readouterr()
    assert (
        main(["replay", "show", str(path), "--format", "waymo", "--out", str(tmp_path / "x.gif"), "--follow", "99"])
        == 2
    )
    assert "--follow 99: no road user of that id in the recording (ego: 1)" in capsys.readouterr().err
