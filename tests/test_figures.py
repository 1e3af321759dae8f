"""bench/figures.py on the real simulator: Fig. 6 of a test case replayed as the evaluation plays it, Fig. 5
from a tiny train_log.csv, Sec. 5.5's table, and the one-line errors. Nothing is trained."""
import json
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

import figures  # noqa: E402
import experiment  # noqa: E402
import tarl  # noqa: E402
import world  # noqa: E402

HEADER = "step,loop,episode_return,success,collision,timeout,crossing_time,mean_beta\n"


def png_shape(path: Path):
    image = matplotlib.image.imread(path)
    assert image[..., :3].std() > 0.05, "a blank image"
    return image.shape


def test_case_replays_case_2_of_round_0_as_the_evaluation_and_draws_it(tmp_path):
    env = world.DrivingEnv(world.EnvConfig(scenario="intersection"))
    small = tarl.TrainConfig(steps=100, log_every=10**9, checkpoint_every=10**9)
    # Table 2's network sizes (make_trainer builds those), a small buffer; an untrained TARL
    trainer = tarl.Trainer(env, "tarl", small, tarl.SACConfig(buffer_size=1000), out=tmp_path, log=lambda *a: None)
    trainer.save()
    assert (tmp_path / "ckpt.pt").is_file() and (tmp_path / "policy.pt").is_file()
    expected = experiment.play_round(env, [trainer.driver], 3, 0, 0)[0][2]  # the evaluation's case 2 of round 0
    env.close()

    out = tmp_path / "fig6.png"
    ep = figures.main(["case", "--scenario", "intersection", "--algo", "tarl", "--load", str(tmp_path / "policy.pt"),
                       "--seed", "0", "--round", "0", "--case", "2", "--cases", "3", "--out", str(out)])
    assert png_shape(out)[:2] == (1430, 2210)
    # the same test case, played as the evaluation played it
    assert (ep["start"], ep["outcome"], ep["steps"]) == (expected["start"], expected["outcome"], expected["steps"])
    np.testing.assert_array_equal(ep["a_bar"], expected["a_bar"])
    n = ep["steps"]
    # the record: Eq. (11) and Eq. (12) at every step, a timing in 1..T_max, one frame per decision and the last state
    assert np.all((ep["T"] >= 1) & (ep["T"] <= tarl.TimingConfig().t_max))
    np.testing.assert_allclose(ep["beta"], tarl.beta(ep["T"], omega=tarl.TimingConfig().omega))
    np.testing.assert_allclose(ep["a_bar"], tarl.blend(ep["a"], ep["a_base"], ep["beta"]), atol=1e-12)
    assert len(ep["frames"]) == len(ep["ego"]) == len(ep["plan"]) == n + 1
    # each frame is env.snapshot() (scene.py draws it) with who drove the step from it: the rollout's T and beta
    assert [f["beta"] for f in ep["frames"][:n]] == ep["beta"].tolist() and [f["T"] for f in ep["frames"][:n]] == ep["T"].tolist()
    np.testing.assert_allclose([f["ego"] for f in ep["frames"]], ep["ego"])
    # the scene holds every vehicle: among them, the rollout's (those within d_max of the ego)
    for k in range(n):
        seen, every = ep["others"][k], ep["frames"][k]["vehicles"]
        assert all(np.abs(every - row).sum(1).min() < 1e-6 for row in seen)
        near = np.hypot(*(every[:, :2] - ep["ego"][k][:2]).T) < world.EnvConfig().perception - world.EnvConfig().length
        assert all(len(seen) and np.abs(seen - row).sum(1).min() < 1e-6 for row in every[near])
    # five snapshots from the departure to leaving the conflict area (or the episode's end)
    frames, end = figures.snapshot_frames(ep, until_collision=False)
    zones = [f["zone"] for f in ep["frames"]]
    assert frames[0] == 0 and frames[-1] == end and len(frames) == 5 and np.all(np.diff(frames) > 0)
    assert end == (zones.index(2) if 2 in zones else n)
    assert all(z == 0 for z in zones[:zones.index(1)]) if 1 in zones else True


def write_log(folder: Path, rows):
    folder.mkdir(parents=True)
    (folder / "train_log.csv").write_text(HEADER + "".join(",".join(map(str, r)) + "\n" for r in rows))


def test_settling_tests_a_learned_timing_over_the_last_two_tenths_of_training(tmp_path):
    """Is the timing taker still changing? Its episodes' mean beta over the last tenth against the tenth before,
    paired by seed; rows whose timing is fixed (T = 2, T random, SAC-Lattice's switch) have none to learn."""
    for seed, (before, last) in enumerate([(0.2, 0.3), (0.1, 0.4)]):
        write_log(tmp_path / f"roundabout-tarl-s{seed}", [(100, "step1", 0, 0, 1, 0, "", ""),
                                                          (850, "real", 9, 1, 0, 0, 9.0, before),
                                                          (880, "imagination", 9, 1, 0, 0, 9.0, 0.9),
                                                          (950, "real", 9, 1, 0, 0, 9.0, last)])
        write_log(tmp_path / f"roundabout-tarl-fixed-t-s{seed}", [(850, "real", 9, 1, 0, 0, 9.0, 0.5),
                                                                  (950, "real", 9, 1, 0, 0, 9.0, 0.5)])
    # differences 0.1 and 0.3: d = 0.2, sd = 0.141, t = 2 on one degree of freedom, p = 0.295
    assert figures.settling(figures.find_runs(tmp_path), 1000) == [
        "roundabout, TARL: mean beta, the last tenth of training against the tenth before: +0.200 (95 % CI -1.071 to "
        "+1.471), paired t p 0.3 (Holm 0.3), n = 2, higher on 2"]


def test_training_draws_real_episodes_of_a_tiny_log_and_rejects_a_missing_folder(tmp_path, capsys):
    runs = tmp_path / "runs"
    # step 1 until 300, then the imagination (returns of 99, which must not show) and the real environment
    write_log(runs / "intersection-tarl-s0", [(100, "step1", 10, 1, 0, 0, 9.0, ""), (300, "step1", -20, 0, 1, 0, "", ""),
                                              (350, "imagination", 99, 1, 0, 0, 5.0, 0.2),
                                              (500, "real", 30, 1, 0, 0, 8.0, 0.3), (600, "real", -10, 0, 1, 0, "", 0.1),
                                              (700, "imagination", 99, 0, 1, 0, "", 0.2)])
    write_log(runs / "intersection-sac-s1", [(200, "step1", 0, 0, 1, 0, "", ""), (650, "real", 5, 0, 0, 1, "", "")])
    log = figures.read_log(runs / "intersection-tarl-s0" / "train_log.csv")
    assert figures.step_one_end(log) == 300
    np.testing.assert_allclose(figures.binned(log, "episode_return", 350, 2, 1), [-5.0, 10.0])  # no 99 in either bin
    np.testing.assert_allclose(figures.binned(log, "collision", 350, 2, 1), [0.5, 0.5])
    # beta: the real loop's episodes only, none in step 1 (no blend): the third row, where the timing settles
    np.testing.assert_allclose(figures.binned(log, "mean_beta", 350, 2, 1), [np.nan, 0.2])
    # a bin of one episode (the last of step 1, say) is blank by default: one episode is not a rate
    np.testing.assert_allclose(figures.binned(log, "collision", 350, 2, 2), [0.5, 0.5])
    np.testing.assert_allclose(figures.binned(log, "collision", 250, 3), [np.nan, np.nan, np.nan])
    np.testing.assert_allclose(figures.binned(log, "collision", 200, 4, 2), [np.nan, np.nan, 0.5, np.nan])
    mean, low, high = figures.over_seeds(np.array([[1.0, np.nan], [3.0, np.nan]]))
    assert mean[0] == 2.0 and (low[0], high[0]) == (1.0, 3.0) and np.isnan(mean[1])

    out = tmp_path / "fig5.png"
    figures.main(["training", "--runs", str(runs), "--out", str(out)])
    assert png_shape(out)[1] > 500
    with pytest.raises(SystemExit) as e:
        figures.main(["training", "--runs", str(tmp_path / "missing"), "--out", str(out)])
    assert str(e.value) == f"figures.py: --runs {tmp_path / 'missing'}: no such folder"
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no SCENARIO-ALGO-sSEED/train_log.csv"):
        figures.main(["training", "--runs", str(tmp_path / "empty")])
    # another budget's runs (bench/table3.py names them S-A-sK-500k) are drawn apart, not into the default's
    write_log(runs / "intersection-tarl-s0-500k", [(100, "step1", 10, 1, 0, 0, 9.0, ""), (900, "real", 40, 1, 0, 0, 8.0, 0.3)])
    assert set(figures.find_runs(runs)) == {("intersection", "tarl"), ("intersection", "sac")}
    assert figures.find_runs(runs)[("intersection", "tarl")][0]["step"].max() == 700
    assert list(figures.find_runs(runs, "500k")) == [("intersection", "tarl")]
    figures.main(["training", "--runs", str(runs), "--budget", "500k", "--out", str(out)])
    with pytest.raises(SystemExit, match="no SCENARIO-ALGO-sSEED-50k/train_log.csv"):
        figures.main(["training", "--runs", str(runs), "--budget", "50k", "--out", str(out)])


def eval_json(path: Path, outcomes, **row) -> Path:
    cases = [dict(round=0, case=c, start=f"{c:016x}", outcome=o, crossing_time=10.0 if o == "arrival" else None,
                  steps=50) for c, o in enumerate(outcomes)]
    path.write_text(json.dumps(dict(scenario="intersection", seed=0, rows=[
        dict(algo="lattice-idm", label="Lattice-IDM", cases_per_round=len(cases), cases=cases, **row)])))
    return path


def test_failure_and_case_refuse_bad_input_in_one_line_before_simulating(tmp_path):
    calm = eval_json(tmp_path / "eval.json", ["arrival", "timeout", "arrival"])
    base = ["failure", "--scenario", "intersection", "--algo", "lattice-idm", "--eval"]
    with pytest.raises(SystemExit) as e:
        figures.main(base + [str(calm)])
    assert str(e.value) == f"figures.py: --eval {calm}: lattice-idm has no collision in its 3 test cases"
    with pytest.raises(SystemExit, match="no such file"):
        figures.main(base + [str(tmp_path / "missing.json")])
    with pytest.raises(SystemExit, match="no row --algo tarl"):
        figures.main(["failure", "--scenario", "intersection", "--algo", "tarl", "--load", "x.pt", "--eval", str(calm)])
    with pytest.raises(SystemExit, match="is of the intersection, not --scenario roundabout"):
        figures.main(["failure", "--scenario", "roundabout", "--algo", "lattice-idm", "--eval", str(calm)])
    with pytest.raises(SystemExit) as e:
        figures.main(["case", "--scenario", "intersection", "--algo", "lattice-idm", "--case", "3", "--cases", "3"])
    assert "beyond the round" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(SystemExit, match="checkpoint not found"):
        figures.main(["case", "--scenario", "intersection", "--case", "0", "--load", str(tmp_path / "missing.pt")])


def test_beta_table_groups_the_timings_and_quotes_the_paper(tmp_path, capsys):
    share = [0.5, 0.1, 0.1, 0.2, 0.1, 0, 0, 0, 0, 0]
    path = eval_json(tmp_path / "eval.json", ["arrival", "collision"],
                     beta_minus={"all_steps": 0.4, "3s_before_collision": 0.6, "1s_before_collision": 0.8},
                     timing_share={"all_steps": share, "3s_before_collision": [0, 0, 1.0] + [0] * 7})
    text = figures.main(["beta", "--eval", str(path), "--out", str(tmp_path / "beta.md")])
    assert "| intersection | Lattice-IDM | 0 | 2 | 1 | 0.400 | 0.600 | 0.800 |" in text
    assert "| 0.500 | 0.200 | 0.300 | 0.000 | 1.000 | 0.000 |" in text  # T = 1, 2-3, >= 4; the same before collisions
    assert (tmp_path / "beta.md").read_text() == text + "\n"
    assert figures.PAPER_BETA_MINUS == {"intersection": (0.495, 0.657, 0.859), "roundabout": (0.663, 0.839, 0.872)}


def test_constraint_draws_j_c_and_lambda_and_tabulates_lambda(tmp_path):
    runs = tmp_path / "runs"
    for folder, text in (("roundabout-sac-lag-s0", "step,J_c,lambda\n100,0.2,0.015\n200,0.1,0.02\n300,0.0,0.0\n"),
                         ("roundabout-sac-lag-s1", "step,J_c,lambda\n150,0.04,0.0\n250,0.06,0.001\n"),
                         ("roundabout-cpo-s0", "step,J_c,cpo_case,trial\n2048,0.3,1,3\n4096,0.1,3,0\n")):
        (runs / folder).mkdir(parents=True)
        (runs / folder / "constraint_log.csv").write_text(text)
    out = tmp_path / "fig.png"
    text = figures.main(["constraint", "--runs", str(runs), "--out", str(out)])
    assert png_shape(out)[2] in (3, 4)
    assert "| roundabout | SAC-Lag | 0 | 3 | 0.000 | 0.020 | 0.000 | 0.67 |" in text
    assert "| roundabout | SAC-Lag | 1 | 2 | 0.060 | 0.001 | 0.001 | 0.50 |" in text
    assert "| roundabout | CPO | 0 | 2 | 0.100 | - | - | - |" in text
    with pytest.raises(SystemExit, match="no SCENARIO-ALGO-sSEED/constraint_log.csv"):
        figures.main(["constraint", "--runs", str(tmp_path / "nothing"), "--out", str(out)])
