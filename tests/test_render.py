"""The scene from above on the real simulator: scene.py's network against SUMO's, env.render()'s frames, the
GIFs of bench/video.py (a frame per step, at real time) and its one-line errors. No pixel is compared with a
stored image; nothing is trained."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from PIL import Image

import experiment
import scene
import tarl
import world

ROOT = Path(__file__).resolve().parents[1]
import video  # noqa: E402


def test_shapes_and_colours_by_hand():
    # a straight lane 10 m long and 3 m wide along +x: the rectangle around it
    np.testing.assert_allclose(scene.lane_polygon(np.array([[0.0, 0.0], [10.0, 0.0]]), 3.0),
                               [[0, 1.5], [10, 1.5], [10, -1.5], [0, -1.5]])
    assert scene.lane_polygon(np.array([[1.0, 1.0], [1.0, 1.0]]), 3.0).shape == (0, 2)  # a point has no area
    # a 4 x 2 m box at (1, 2) heading +y: 4 m along y
    corners = scene.boxes(np.array([1.0, 2.0, np.pi / 2]), 4.0, 2.0)
    np.testing.assert_allclose(np.sort(corners[0], axis=0), [[0, 0], [0, 0], [2, 4], [2, 4]], atol=1e-12)
    # the ego's colour: the actor's at beta = 1 (and unknown), the planner's at 0, the blend between
    actor, planner = np.array(to_rgb(scene.ACTOR)), np.array(to_rgb(scene.PLANNER))
    np.testing.assert_allclose(scene.ego_color(1.0), actor)
    np.testing.assert_allclose(scene.ego_color(None), actor)
    np.testing.assert_allclose(scene.ego_color(0.0), planner)
    np.testing.assert_allclose(scene.ego_color(0.25), 0.25 * actor + 0.75 * planner)
    # the view: the junction's centre, moved just enough to keep the ego 10 m inside a 120 m window
    np.testing.assert_allclose(scene.view_centre([0, 0], [30.0, -20.0]), [0, 0])
    np.testing.assert_allclose(scene.view_centre([0, 0], [-75.0, 5.0]), [-25.0, 0.0])


def test_import_world_loads_no_matplotlib():
    code = "import sys, world; assert 'matplotlib' not in sys.modules and 'scene' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def pixels(frame, color) -> int:
    """How many pixels of the frame have exactly this RGB (0-1) colour (the inside of a filled shape)."""
    return int(np.all(frame == np.round(255 * np.asarray(color)).astype(np.uint8), axis=-1).sum())


def test_network_is_sumos_and_render_draws_each_step_and_who_drives():
    env = world.DrivingEnv(world.EnvConfig(scenario="intersection"), render_mode="rgb_array")
    try:
        env.reset(seed=3)
        # the network read from the .net.xml is the one libsumo has: the same lanes, shapes and widths
        sim, net = env.sim, scene.network(env.net_file)
        lanes = sorted((lane.startswith(":"), sim.lane.getWidth(lane), np.round(sim.lane.getShape(lane), 2).tolist())
                       for lane in sim.lane.getIDList())
        assert lanes == sorted((internal, w, np.round(s, 2).tolist()) for s, w, internal in net["lanes"])
        junctions = [np.round(sim.junction.getShape(j), 2).tolist() for j in sim.junction.getIDList() if j[0] != ":"]
        assert sorted(junctions) == sorted(np.round(j, 2).tolist() for j in net["junctions"])
        # a frame of each step: 480 x 480 RGB; the ego moves, the frame changes
        first = env.render()
        assert first.shape == (480, 480, 3) and first.dtype == np.uint8
        assert pixels(first, scene.ego_color(None)) > 30  # nobody told the env who drives: the agent, the actor's colour
        for _ in range(3):
            env.step([env.base_action()])
        env.show(None, 0.0)  # the planner drives
        frame = env.render()
        assert frame.shape == first.shape and np.abs(frame.astype(int) - first).sum() > 0
        assert pixels(frame, scene.ego_color(0.0)) > 30 and pixels(frame, scene.ego_color(1.0)) == 0
        env.show(2, 0.5)
        assert pixels(env.render(), scene.ego_color(0.5)) > 30
    finally:
        env.close()


def test_video_has_a_frame_per_step_at_real_time_and_matches_the_evaluation(tmp_path):
    # the evaluation of Lattice-IDM on round 0 of one case, as eval.json keeps it
    env = world.DrivingEnv(world.EnvConfig(scenario="intersection"))
    ep = experiment.play_round(env, [tarl.Driver("planner")], 1, 0, 0)[0][0]
    env.close()
    case = {k: ep[k] for k in experiment.CASE_KEYS}
    evaluation = tmp_path / "eval.json"
    evaluation.write_text(json.dumps(dict(scenario="intersection", seed=0, rows=[dict(algo="lattice-idm", cases=[case])])))
    out = tmp_path / "v.gif"
    args = ["--scenario", "intersection", "--round", "0", "--case", "0", "--cases", "1", "--left", "lattice-idm",
            "--eval", str(evaluation), "--out", str(out)]
    played, = video.main(args)
    assert (played["start"], played["outcome"], played["steps"]) == (ep["start"], ep["outcome"], ep["steps"])
    gif = Image.open(out)
    assert gif.n_frames == ep["steps"] + 1  # every simulator step, and the state the episode ended in
    durations = []
    for k in range(gif.n_frames):
        gif.seek(k)
        durations.append(gif.info["duration"])
    assert durations == [200] * ep["steps"] + [2000]  # dt = 0.2 s: real time; the end held 2 s (--hold)
    assert gif.size[0] == 480 and 560 < gif.size[1] < 640
    # another start recorded: not the evaluated case, one line and no GIF
    evaluation.write_text(json.dumps(dict(scenario="intersection", seed=0, rows=[dict(algo="lattice-idm",
                                                                                      cases=[{**case, "start": "0" * 16}])])))
    out.unlink()
    with pytest.raises(SystemExit, match="not the evaluated case or model") as e:
        video.main(args)
    assert "\n" not in str(e.value) and not out.exists()


@pytest.mark.parametrize("args, message", [
    (["--case", "3", "--cases", "3", "--left", "lattice-idm"], "--case 3 is beyond the round"),
    (["--case", "0", "--round", "-1", "--left", "lattice-idm"], "count from 0"),
    (["--case", "0", "--left", "lattice"], "unknown algo 'lattice'"),
    (["--case", "0", "--left", "tarl:results/runs/intersection-tarl-s0/policy.pt"], "is for --scenario intersection"),
    (["--case", "0", "--left", "tarl:missing.pt"], "checkpoint not found"),
    (["--left", "lattice-idm"], "required: --case")])
def test_video_errors_are_one_line_before_any_simulation(args, message):
    run = subprocess.run([sys.executable, "bench/video.py", "--scenario", "roundabout", *args], cwd=ROOT,
                         capture_output=True, text=True)
    assert run.returncode != 0 and len(run.stderr.splitlines()) == 1 and message in run.stderr, run.stderr


def test_video_driver_specs():
    ckpt = "results/runs/intersection-tarl-s0/policy.pt"
    side = video.parse_driver(f"tarl:{ckpt}:fixed=1", "intersection", 0)
    assert (side.algo, side.load, side.timing) == ("tarl", Path(ckpt), "fixed=1")
    assert video.parse_driver(f"tarl:{ckpt}", "intersection", 0).timing is None
    assert video.parse_driver("lattice-idm", "roundabout", 0).load is None
    for spec, message in (("sac:x.pt:learned", "needs a timing taker"), ("lattice-idm:x.pt", "takes no checkpoint"),
                          ("tarl", "needs its checkpoint"), ("tarl:x.pt:fixed=0", "with T >= 1")):
        with pytest.raises(SystemExit, match=message):
            video.parse_driver(spec, "roundabout", 0)
