"""The paper's figures of Sec. 5.4-5.5 from this code's runs: Fig. 5 (training curves), Fig. 6 (a test
case, step by step), Fig. 7 (a failure case) and the numbers of Sec. 5.5 (1 - beta, the timings).

    python bench/figures.py training [--runs results/runs] [--out results/fig5_training.png]
    python bench/figures.py case --scenario roundabout --load runs/roundabout-tarl-s0/policy.pt --case 17
    python bench/figures.py failure --scenario intersection --load runs/intersection-tarl-s0/policy.pt \\
        --eval runs/intersection-tarl-s0/eval.json
    python bench/figures.py beta --eval results/runs/*-tarl-s?/eval.json [--out results/sec55_beta.md]
    python bench/figures.py constraint [--runs results/runs] [--out results/fig_constraint.png]

training  Fig. 5: one column per scenario, the episode return and the collision rate over training
          steps of every row of Table 3 found as RUNS/SCENARIO-ALGO-sSEED/train_log.csv, and below them,
          where a row blends, its episodes' mean beta (the actor's share: where the timing settles). Real-environment
          episodes only (Alg. 1 step 1 and the actor loop; the timing imagination is left out). Each seed's
          episodes are averaged over bins of --bin steps (an episode counts in the bin where it ended);
          the line is the mean over seeds, the band their min-max. The dotted line: the end of TARL's
          step 1 (plain SAC), the step of its last "step1" episode.
case      Fig. 6: test case --case of evaluation round --round, replayed exactly as experiment.play_round plays
          it. Top: five snapshots at
          equally spaced moments from the departure to the moment the ego leaves the conflict area; the
          conflict area is zone 1 of the observation's h2 (obs[3:6]: entry road, junction, exit road),
          i.e. from the ego's front leaving the entry road to its front entering the exit road. Middle:
          the actor's, the base planner's and the executed acceleration; bottom: the timing T (beta for
          rows without a timing taker).
failure   Fig. 7: the first test case of --eval's row --algo that ended in a collision (--pick for a
          later one), replayed as `case` (its start fingerprint and its outcome must match the recorded
          ones) and drawn as `case`, the snapshots ending at the collision.
beta      Sec. 5.5: 1 - beta over all steps and in the last 3 s and 1 s before collisions, beside the
          paper's; the share of steps at T = 1, T = 2-3, T >= 4. A markdown table.
constraint  The safe-RL rows (baselines.py): J_c against the limit d, and lambda, over training steps from
          RUNS/SCENARIO-ALGO-sSEED/constraint_log.csv; a markdown table of what lambda did per run.

The snapshots (drawn by scene.py, as DrivingEnv.render() and bench/video.py draw them): --window m square
(120 m), centred on the junction and moved, where needed, just enough to keep the ego 10 m inside; every
vehicle in SUMO, not only the ones the ego perceives: those within d_max = 60 m of the ego (Eq. (27)) in
grey, the rest in light grey; the humans in the level-k game with the ego outlined in the colour of their
choice (cross or yield); the ego in the colour of who drives the step: the actor (beta = 1), the planner
(beta = 0), or between them by beta.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
import tempfile
import textwrap
import time
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]
import baselines  # noqa: E402
import experiment  # noqa: E402
import scene  # noqa: E402
import tarl  # noqa: E402
import world  # noqa: E402
from analysis import claims  # noqa: E402
from table3 import ABLATIONS, NAMES, ROWS, SCENARIOS  # noqa: E402

plt.rcParams.update({"font.size": 11, "axes.titlesize": 11, "axes.labelsize": 11, "legend.fontsize": 10,
                     "xtick.labelsize": 9, "ytick.labelsize": 9})
ORDER = tuple(a for a in ROWS + ABLATIONS if a != "lattice-idm")  # the learned rows of Table 3, in its order
FIG5 = tuple(a for a in ROWS if a != "lattice-idm") + ABLATIONS[:2]  # Fig. 5's rows unless --algos: and the ablations
COLORS = {"tarl": "#d62728", "sac": "#1f77b4", "sac-lattice": "#2ca02c", "sac-lag": "#9467bd", "sac-pid": "#8c564b",
          "ppo-lag": "#e377c2", "cpo": "#7f7f7f", "tarl-fixed-t": "#ff7f0e", "tarl-random-t": "#17becf",
          "tarl-consistent": "#bcbd22", "tarl-held": "#aec7e8", "tarl-utd": "#ff9896", "tarl-actor-target": "#393b79",
          "tarl-rare-replay": "#637939", "tarl-min-target": "#843c39"}
# Sec. 5.5 of the paper: mean 1 - beta over all steps, within 3 s and 1 s before a collision
PAPER_BETA_MINUS = {"intersection": (0.495, 0.657, 0.859), "roundabout": (0.663, 0.839, 0.872)}
RUN_NAME = re.compile(r"^(?P<scenario>[a-z]+)-(?P<algo>[a-z0-9-]+)-s(?P<seed>\d+)(?:-(?P<budget>\d+k))?$")  # bench/table3.py
ACTOR, BASE, EXECUTED, TIMING = scene.ACTOR, scene.PLANNER, "#ff7f0e", "#6a3d9a"  # Fig. 6's colours
DPI = 130
MIN_EPISODES = 3  # a training-curve bin with fewer real episodes is left blank (one episode is not a rate)


def fail(message: str):
    raise SystemExit(f"figures.py: {message}")


def progress(message: str):
    print(message, file=sys.stderr, flush=True)


def name(algo: str) -> str:
    return NAMES.get(algo, algo)


# ---- Fig. 5: training curves ---------------------------------------------------------------------


def read_log(path: Path) -> dict:
    """train_log.csv -> arrays step, loop, episode_return, collision and mean_beta (nan where the episode had no
    beta: step 1, or a row without a timing) (one entry per episode)."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        if rows and not {"step", "loop", "episode_return", "collision"} <= set(rows[0]):
            fail(f"{path} lacks the columns step, loop, episode_return, collision: is it a tarl.py train_log.csv?")
        return {"step": np.array([int(r["step"]) for r in rows], dtype=np.int64),
                "loop": np.array([r["loop"] for r in rows], dtype=object),
                "episode_return": np.array([float(r["episode_return"]) for r in rows]),
                "collision": np.array([float(r["collision"]) for r in rows]),
                "mean_beta": np.array([float(r.get("mean_beta") or "nan") for r in rows])}
    except (OSError, ValueError, TypeError) as e:
        fail(f"cannot read {path}: {e}")


def find_runs(folder: Path, budget: str | None = None) -> dict:
    """{(scenario, algo): {seed: log}} of every SCENARIO-ALGO-sSEED/train_log.csv in folder (the default budget),
    or of every SCENARIO-ALGO-sSEED-BUDGET/train_log.csv (another budget, as 500k)."""
    if not folder.is_dir():
        fail(f"--runs {folder}: no such folder")
    runs = defaultdict(dict)
    for path in sorted(folder.glob("*/train_log.csv")):
        m = RUN_NAME.match(path.parent.name)
        if not m or m["scenario"] not in SCENARIOS:
            progress(f"skipping {path}: its folder is not named SCENARIO-ALGO-sSEED")
            continue
        if m["budget"] == budget:
            runs[m["scenario"], m["algo"]][int(m["seed"])] = read_log(path)
    if not runs:
        fail(f"no SCENARIO-ALGO-sSEED{'-' + budget if budget else ''}/train_log.csv in {folder}")
    return runs


def step_one_end(log: dict) -> int | None:
    """The step at which Algorithm 1's step 1 ended: that of its last episode (None without one)."""
    steps = log["step"][log["loop"] == "step1"]
    return int(steps.max()) if len(steps) else None


def binned(log: dict, key: str, bin_steps: int, n_bins: int, min_episodes: int = MIN_EPISODES) -> np.ndarray:
    """The mean of `key` over the real-environment episodes ending in each bin of bin_steps that have it (nan if
    fewer than min_episodes: e.g. the bin where step 1 ends just before the timing imagination's first steps)."""
    real = (log["loop"] != "imagination") & np.isfinite(log[key])
    idx = np.minimum((log["step"][real] - 1) // bin_steps, n_bins - 1)
    count = np.bincount(idx, minlength=n_bins)
    total = np.bincount(idx, weights=log[key][real], minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count >= max(min_episodes, 1), total / np.maximum(count, 1), np.nan)


def over_seeds(curves: np.ndarray):
    """(seeds, bins) -> mean, min, max over the seeds that have a value in each bin."""
    have = ~np.isnan(curves)
    n = have.sum(0)
    filled = np.where(have, curves, 0.0)
    mean = np.where(n > 0, filled.sum(0) / np.maximum(n, 1), np.nan)
    low = np.where(n > 0, np.where(have, curves, np.inf).min(0), np.nan)
    high = np.where(n > 0, np.where(have, curves, -np.inf).max(0), np.nan)
    return mean, low, high


def training(args):
    runs = find_runs(args.runs, args.budget)
    if args.algos != ["all"]:  # Table 3's learned rows and the two ablations unless asked: the variants crowd it
        runs = {k: v for k, v in runs.items() if k[1] in (args.algos or FIG5)}
    if args.bin is not None and args.bin < 1:
        fail("--bin is a number of steps: at least 1")
    ends = [int(log["step"].max()) for seeds in runs.values() for log in seeds.values() if len(log["step"])]
    if not ends:
        fail(f"the train_log.csv files in {args.runs} hold no episode yet")
    longest = max(ends)
    bin_steps = args.bin or max(1, min(5000, longest // 20))
    n_bins = max(1, longest // bin_steps)  # a last, partial bin joins the one before (runs overshoot a little)
    scenarios = [s for s in SCENARIOS if any(sc == s for sc, _ in runs)]
    algos = [a for a in ORDER if any(al == a for _, al in runs)] + sorted({a for _, a in runs} - set(ORDER))
    # a third row where a drawn run has a timing: beta, the actor's share of the executed action (Eqs. (6), (12))
    keys = ("episode_return", "collision") + ("mean_beta",) * any(
        np.isfinite(log["mean_beta"]).any() for seeds in runs.values() for log in seeds.values())
    fig, axes = plt.subplots(len(keys), len(scenarios), figsize=(6.5 * len(scenarios), 4 * len(keys)), squeeze=False,
                             sharex="col")
    x = (np.arange(n_bins) + 0.5) * bin_steps
    drawn, step_ones = {}, set()
    for col, scenario in enumerate(scenarios):
        for algo in algos:
            seeds = runs.get((scenario, algo))
            if not seeds:
                continue
            color = COLORS.get(algo, f"C{len(drawn) % 10}")
            for row, key in enumerate(keys):
                mean, low, high = over_seeds(np.array([binned(log, key, bin_steps, n_bins) for log in seeds.values()]))
                ax = axes[row, col]
                ax.fill_between(x, low, high, color=color, alpha=0.18, linewidth=0)
                ax.plot(x, mean, color=color, lw=1.8, ls="--" if algo in ABLATIONS else "-",  # dashed: not a row of Table 3
                        marker="o" if np.isfinite(mean).sum() < 3 else None, ms=4)
            drawn.setdefault(algo, set()).add(len(seeds))
            if algo.startswith("tarl"):
                for log in seeds.values():
                    end = step_one_end(log)
                    if end is not None and algo == "tarl":
                        step_ones.add(end)
                        for row in range(len(keys)):
                            axes[row, col].axvline(end, color="k", ls=":", lw=1.3)
        axes[-1, col].set_xlim(0, max(int(log["step"].max()) for (sc, _), seeds in runs.items() if sc == scenario
                                     for log in seeds.values() if len(log["step"])))
        axes[0, col].set_title(f"{scenario.capitalize()} scenario")
        axes[0, col].set_ylabel("episode return")
        axes[1, col].set_ylabel("collision rate")
        axes[1, col].set_ylim(-0.03, 1.03)
        if len(keys) > 2:
            axes[2, col].set_ylabel("mean beta of an episode")
            axes[2, col].set_ylim(-0.03, 1.03)
        axes[-1, col].set_xlabel("training step (simulator steps)")
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
            ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0), useMathText=True)
    handles = [Line2D([], [], color=COLORS.get(a, "C0"), lw=2, ls="--" if a in ABLATIONS else "-",
                      label=f"{name(a)} ({'/'.join(map(str, sorted(n)))} seed{'s' * (max(n) > 1)})") for a, n in drawn.items()]
    if step_ones:
        handles.append(Line2D([], [], color="k", ls=":", lw=1.3, label="end of TARL's step 1 (plain SAC)"))
    # below the panels, in inches from the bottom: the caption, then the legend
    caption = textwrap.fill(f"Real-environment episodes only (timing imagination excluded); each seed's episodes averaged "
                            f"over bins of {bin_steps:,} steps (blank: fewer than {MIN_EPISODES} episodes). Line: mean over "
                            "seeds; band: min-max over seeds." + " Mean beta: over an episode's steps, the actor's share of "
                            "the executed acceleration (Eqs. (6), (12); 1: the actor alone, 0: the planner), of the rows "
                            "that blend (not in step 1)." * (len(keys) > 2), 75 * len(scenarios))
    ncol = min(4 if len(scenarios) > 1 else 2, len(handles))
    height = fig.get_figheight()
    caption_top = 0.1 + 0.19 * (caption.count("\n") + 1)
    legend_top = caption_top + 0.08 + 0.3 * math.ceil(len(handles) / ncol)
    fig.text(0.5, 0.1 / height, caption, ha="center", va="bottom", fontsize=9, color="0.3")
    fig.legend(handles=handles, loc="lower center", ncol=ncol, frameon=False, bbox_to_anchor=(0.5, caption_top / height))
    fig.suptitle("Training curves (Fig. 5)", fontsize=13)
    fig.tight_layout(rect=(0, (legend_top + 0.05) / height, 1, 1))
    save(fig, args.out)
    for line in settling(runs, longest):
        print(line)


def settling(runs: dict, steps: int) -> list[str]:
    """Is a learned timing still changing at the end of training? For each row with a timing taker and two or more
    seeds: its episodes' mean beta over the last tenth of the steps against the tenth before, the difference paired
    by seed (analysis.claims.paired_t: Student's paired t, two-sided), Holm-adjusted over the rows tested."""
    tests = []
    for (scenario, algo), seeds in sorted(runs.items()):
        if experiment.ROWS.get(algo) and experiment.ROWS[algo].timing == "taker" and len(seeds) >= 2:
            tenths = {k: binned(log, "mean_beta", steps // 10, 10, 1)[-2:] for k, log in seeds.items()}
            tests.append((f"{scenario}, {name(algo)}", claims.paired_t({k: v[1] for k, v in tenths.items()},
                                                                      {k: v[0] for k, v in tenths.items()})))
    return [f"{row}: mean beta, the last tenth of training against the tenth before: {t['d']:+.3f} (95 % CI "
            f"{t['ci'][0]:+.3f} to {t['ci'][1]:+.3f}), paired t p {t['p']:.2g} (Holm {p:.2g}), n = {t['n']}, higher "
            f"on {int((t['diffs'] > 0).sum())}" for (row, t), p in zip(tests, claims.holm([t["p"] for _, t in tests]))]


def save(fig, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI)
    plt.close(fig)
    print(f"wrote {out}")


# ---- Figs. 6 and 7: one test case ------------------------------------------------------------


class Watch:
    """A driver that also keeps, at each of its decisions, the scene (env.snapshot(): every vehicle in SUMO,
    not only the rollout's within d_max of the ego) with the T and beta it chose. It acts exactly as its driver."""

    def __init__(self, driver: tarl.Driver):
        self.driver, self.frames = driver, []

    def new_episode(self, seed=None):
        self.driver.new_episode(seed)

    def act(self, obs, env: world.DrivingEnv, deterministic=False, a=None):
        a, T, b = self.driver.act(obs, env, deterministic, a)
        self.frames.append({**env.snapshot(), "T": T, "beta": b})  # who drives the step from this state
        return a, T, b


def make_driver(args, env: world.DrivingEnv) -> tuple[tarl.Driver, str]:
    """The row's driver: Lattice-IDM, or the checkpoint's networks (loaded before any simulation), timed as
    args.timing says if it is given (experiment.timing_override: learned, phased, random, fixed=T, cap=T)."""
    if args.algo == "lattice-idm":
        return tarl.Driver("planner"), name("lattice-idm")
    if args.load is None:
        fail(f"--algo {args.algo} needs --load CKPT (a ckpt.pt or policy.pt of tarl.py)")
    state = experiment.load_checkpoint(args.load, args.scenario, args.algo)
    try:
        tc = tarl.TrainConfig(timing=experiment.checkpoint_timing(state))
        trainer = experiment.make_trainer(args.algo, env, tc, args.seed, None, lambda *a: None, state=state)
        trainer.load(state, resume=False)
    except (RuntimeError, KeyError, AttributeError) as e:
        fail(f"cannot load {args.load} as --algo {args.algo}: {str(e).splitlines()[0][:200]}")
    label = f"{name(args.algo)} ({state['step']:,} training steps)"
    if getattr(args, "timing", None):
        return experiment.timing_override(args.timing, trainer), f"{label}, timing {experiment.timing_name(args.timing)}"
    return trainer.driver, label


def replay(env: world.DrivingEnv, drivers: list[tarl.Driver], seed: int, round_: int, case: int) -> list[dict]:
    """Test case `case` of round `round_` played by each driver as experiment.play_round plays it (a case is
    the same episode whether played alone or within its round). Per driver, the rollout's record with
    "frames": the scene at each decision (Watch) and, as one more frame, the state the episode ended in."""
    progress(f"recording test cases 0-{case} of round {round_} (seed {experiment.test_seed(seed, round_)}): "
             f"{env.cfg.warmup + (case + 1) * env.cfg.case_gap:,.0f} s of traffic")
    t0, episodes = time.time(), []
    with tempfile.TemporaryDirectory() as folder:
        cases = env.record_cases(experiment.test_seed(seed, round_), case + 1, folder)
        for driver in drivers:
            watch = Watch(driver)
            ep = experiment.rollout(env, watch, {"case": cases[case]}, record=True)
            # the episode's last state, driven into by the last step's T and beta
            last = {**env.snapshot(), "T": watch.frames[-1]["T"], "beta": watch.frames[-1]["beta"]}
            ep["frames"] = watch.frames + [last]
            ep["ego"] = np.vstack([ep["ego"], last["ego"]])
            ep["others"] = ep["others"] + [env.others[:, [0, 1, 3]].copy()]
            ep["plan"] = ep["plan"] + [last["plan"]]
            ep["net"] = scene.network(env.net_file)
            progress(f"  case {case}: {ep['outcome']} after {ep['steps']} steps [{time.time() - t0:.0f} s]")
            episodes.append(ep)
    return episodes


def snapshot_frames(ep: dict, until_collision: bool) -> tuple[list[int], int]:
    """Five equally spaced frames from the departure (frame 0) to the first frame with the ego's front on
    the exit road (the last frame if it never got there, and with until_collision)."""
    zones = np.array([f["zone"] for f in ep["frames"]])
    exit_ = np.flatnonzero(zones == 2)
    end = len(zones) - 1 if until_collision or not len(exit_) else int(exit_[0])
    return sorted(set(np.round(np.linspace(0, end, 5)).astype(int).tolist())), end


def partner(ep: dict, cfg: world.EnvConfig) -> str | None:
    """The vehicle the ego collided with: one overlapping it in the last frame, else the nearest."""
    f = ep["frames"][-1]
    ego = f["ego"]
    if not f["ids"]:
        return None
    xy, h = f["vehicles"][:, :2], f["vehicles"][:, 2]
    hit = world.boxes_overlap(ego[:2], ego[2], xy, h, cfg.length, cfg.width)
    d = np.hypot(*(xy - ego[:2]).T)
    return f["ids"][int(np.argmax(hit)) if hit.any() else int(np.argmin(d))]


def draw_case(ep: dict, cfg: world.EnvConfig, title: str, out: Path, window: float, until_collision: bool = False):
    frames, end = snapshot_frames(ep, until_collision)
    dt, n = cfg.dt, ep["steps"]
    t = np.arange(n) * dt
    zones = np.array([f["zone"] for f in ep["frames"]])
    culprit = partner(ep, cfg) if ep["outcome"] == "collision" else None

    fig = plt.figure(figsize=(17, 11))
    gs = fig.add_gridspec(3, len(frames), height_ratios=[3.3, 2.0, 1.4], hspace=0.32, wspace=0.12,
                          left=0.055, right=0.985, top=0.84, bottom=0.06)
    centre, half = scene.junction_centre(ep["net"]), window / 2
    for i, k in enumerate(frames):
        ax = fig.add_subplot(gs[0, i])
        f = ep["frames"][k]
        c = scene.view_centre(centre, f["ego"][:2], window)  # centred on the junction, moved to keep the ego inside
        scene.draw_network(ax, ep["net"])
        scene.Layers(ax).update(f)
        if culprit in f["ids"]:
            j = f["ids"].index(culprit)
            ax.add_collection(PolyCollection(scene.boxes(f["vehicles"][j], cfg.length, cfg.width), facecolor="none",
                                             edgecolor="k", lw=2.2, zorder=3))
            ax.text(*(f["vehicles"][j, :2] + 3.5), culprit, fontsize=9, fontweight="bold", clip_on=True, zorder=6,
                    bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
        ax.set_aspect("equal")
        ax.set_xticks(np.arange(-400, 401, 40))
        ax.set_yticks(np.arange(-400, 401, 40))
        ax.set_xlim(c[0] - half, c[0] + half)  # after the ticks, which would widen them
        ax.set_ylim(c[1] - half, c[1] + half)
        ax.tick_params(labelsize=8)
        where = ("entry road", "conflict area", "exit road")[f["zone"]]
        ax.set_title(f"({i + 1}) t = {k * dt:.1f} s, v = {f['v']:.1f} m/s\n{where}"
                     + (", collision" if ep["outcome"] == "collision" and k == len(ep["frames"]) - 1 else ""),
                     fontsize=10)
        if i == 0:
            ax.set_ylabel("y [m]")
        ax.set_xlabel("x [m]", fontsize=9)
    legend = scene.legend_handles(cfg.perception)
    if culprit:
        legend.append(Patch(facecolor=scene.NEAR, edgecolor="k", lw=2.2, label=f"the vehicle it collided with ({culprit})"))
    fig.legend(handles=legend, loc="upper center", ncol=5, frameon=False, bbox_to_anchor=(0.5, 0.93), fontsize=10)

    # the actions, then the timing, over time
    ax_a = fig.add_subplot(gs[1, :])
    ax_t = fig.add_subplot(gs[2, :], sharex=ax_a)
    conflict = np.flatnonzero(zones == 1)
    for ax in (ax_a, ax_t):
        if len(conflict):
            ax.axvspan(conflict[0] * dt, (conflict[-1] + 1) * dt, color="#fdd835", alpha=0.15, lw=0)
        for i, k in enumerate(frames):
            ax.axvline(k * dt, color="0.55", ls=":", lw=1.0)
        ax.grid(alpha=0.3)
    for i, k in enumerate(frames):
        ax_a.text(k * dt, 1.02, f"({i + 1})", transform=ax_a.get_xaxis_transform(), ha="center", va="bottom", fontsize=9)
    if np.isfinite(ep["a"]).any():
        ax_a.plot(t, ep["a"], color=ACTOR, ls="--", lw=1.5, label="actor's action $a_t$", zorder=3)
    ax_a.plot(t, ep["a_base"], color=BASE, ls="--", lw=1.5, label="base planner's action $a_{base}$", zorder=3)
    ax_a.plot(t, ep["a_bar"], color=EXECUTED, lw=2.4, label=r"executed action $\bar a_t$, Eq. (12)", zorder=2)
    ax_a.set_ylim(cfg.a_min - 0.4, cfg.a_max + 1.7)  # the legend above a_max, where no action goes
    ax_a.set_yticks(np.arange(math.ceil(cfg.a_min), math.floor(cfg.a_max) + 1))
    ax_a.set_ylabel("acceleration [m/s$^2$]")
    handles, _ = ax_a.get_legend_handles_labels()
    if len(conflict):
        handles.append(Patch(color="#fdd835", alpha=0.3, label="ego in the conflict area"))
    ax_a.legend(handles=handles, loc="upper left", ncol=len(handles), fontsize=9, framealpha=0.9)
    if (ep["T"] > 0).any():
        ax_t.step(t, ep["T"], where="post", color=TIMING, lw=1.6)
        ax_t.set_ylim(0.5, tarl.TimingConfig().t_max + 0.5)
        ax_t.set_yticks([1, 2, 3, 4, 6, 8, 10])
        ax_t.set_ylabel("timing T [steps]")
        ax_t.text(1.0, 1.02, r"$\beta(1) = 1$, $\beta(2) = 0.5$, $\beta(3) = %.2f$, $\beta(T \geq 4) < 0.05$" % tarl.beta(3, omega=tarl.TimingConfig().omega),
                  transform=ax_t.transAxes, ha="right", va="bottom", fontsize=9, color="0.3")
    else:
        ax_t.step(t, ep["beta"], where="post", color=TIMING, lw=1.6)
        ax_t.set_ylim(-0.05, 1.05)
        ax_t.set_ylabel(r"$\beta$ (no timing taker)")
    ax_t.set_xlabel("time since departure [s]")
    ax_a.set_xlim(0, max(n * dt, frames[-1] * dt + dt))
    plt.setp(ax_a.get_xticklabels(), visible=False)
    fig.suptitle(title, fontsize=13, y=0.985)
    until = ("the collision" if until_collision else
             "the ego's front entering the exit road (leaving the conflict area)" if zones[end] == 2 else
             f"the end of the episode ({ep['outcome']}; the ego never reached the exit road)")
    fig.text(0.5, 0.942, f"Snapshots (1)-({len(frames)}): equally spaced from the departure to {until} at t = {end * dt:.1f} s.",
             ha="center", fontsize=10, color="0.3")
    save(fig, out)


def case_title(label: str, scenario: str, round_: int, case: int, ep: dict, cfg: world.EnvConfig) -> str:
    outcome = {"arrival": f"arrival, crossing time {ep['crossing_time']:.1f} s" if ep["crossing_time"] is not None else "arrival",
               "collision": f"collision at t = {ep['steps'] * cfg.dt:.1f} s",
               "timeout": f"timeout at t = {ep['steps'] * cfg.dt:.0f} s"}[ep["outcome"]]
    return f"{label} on the {scenario}, test round {round_} case {case}: {outcome}"


def check_case_args(args):
    if args.round < 0 or args.case < 0:
        fail("--round and --case count from 0")
    if args.case >= args.cases:
        fail(f"--case {args.case} is beyond the round: it has --cases {args.cases} test cases (0-{args.cases - 1})")
    if args.window <= 20:
        fail("--window is the snapshots' side in metres: give more than 20")


def case(args):
    check_case_args(args)
    torch_threads()
    cfg = world.EnvConfig(scenario=args.scenario)
    env = world.DrivingEnv(cfg)
    try:
        driver, label = make_driver(args, env)
        ep, = replay(env, [driver], args.seed, args.round, args.case)
    finally:
        env.close()
    out = args.out or ROOT / "results" / f"fig6_{args.scenario}.png"
    draw_case(ep, cfg, case_title(label, args.scenario, args.round, args.case, ep, cfg), out, args.window)
    return ep


def read_eval(path: Path) -> dict:
    if not path.is_file():
        fail(f"--eval {path}: no such file")
    try:
        data = experiment.read_eval(path)
        assert isinstance(data["rows"], list) and "scenario" in data
        return data
    except (json.JSONDecodeError, KeyError, AssertionError, UnicodeDecodeError, TypeError):  # TypeError: not a dict
        fail(f"--eval {path} is not an eval.json of tarl.py (a scenario and rows)")


def failure(args):
    data = read_eval(args.eval)
    if data["scenario"] != args.scenario:
        fail(f"--eval {args.eval} is of the {data['scenario']}, not --scenario {args.scenario}")
    rows = [r for r in data["rows"] if r.get("algo") == args.algo]
    if not rows:
        fail(f"--eval {args.eval} has no row --algo {args.algo} (it has {', '.join(r.get('algo', '?') for r in data['rows'])})")
    if args.pick < 0:
        fail("--pick counts the collisions from 0")
    crashes = [c for c in rows[0].get("cases", []) if c["outcome"] == "collision"]
    if len(crashes) <= args.pick:
        fail(f"--eval {args.eval}: {args.algo} collided in {len(crashes)} of its {len(rows[0].get('cases', []))} "
             f"test cases, no collision #{args.pick} to draw" if crashes else
             f"--eval {args.eval}: {args.algo} has no collision in its {len(rows[0].get('cases', []))} test cases")
    crash = crashes[args.pick]
    seed = int(data.get("seed", 0))
    torch_threads()
    cfg = world.EnvConfig(scenario=args.scenario)
    env = world.DrivingEnv(cfg)
    args.seed = seed
    try:
        driver, label = make_driver(args, env)
        progress(f"{args.algo}'s collision #{args.pick}: round {crash['round']} case {crash['case']} "
                 f"({crash['steps']} steps, start {crash['start']})")
        ep, = replay(env, [driver], seed, crash["round"], crash["case"])
    finally:
        env.close()
    if ep["start"] != crash["start"]:
        fail(f"round {crash['round']} case {crash['case']} replayed from start {ep['start']}, but {args.eval} recorded "
             f"{crash['start']}: not the same test case (another SUMO, scenario or seed?)")
    if ep["outcome"] != "collision":
        fail(f"round {crash['round']} case {crash['case']} started as recorded but ended in {ep['outcome']} after "
             f"{ep['steps']} steps, not in the recorded collision after {crash['steps']}: is --load the evaluated model?")
    if ep["steps"] != crash["steps"]:
        progress(f"warning: the replay collided after {ep['steps']} steps, the evaluation after {crash['steps']}")
    out = args.out or ROOT / "results" / f"fig7_{args.scenario}.png"
    draw_case(ep, cfg, "Failure case: " + case_title(label, args.scenario, crash["round"], crash["case"], ep, cfg), out,
              args.window, until_collision=True)
    return ep


def torch_threads():
    import torch
    torch.set_num_threads(1)  # as the evaluation's workers: the same arithmetic, the same decisions


# ---- Sec. 5.5: 1 - beta and the timings ------------------------------------------------------------


def fmt(x, digits=3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def grouped(share) -> list[float | None]:
    """timing_share over T = 1..T_max -> the shares of T = 1, T = 2-3, T >= 4."""
    if share is None:
        return [None] * 3
    s = np.asarray(share, dtype=float)
    return [float(s[0]), float(s[1:3].sum()), float(s[3:].sum())]


def mean_of(values):
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def beta(args):
    found = defaultdict(list)  # (scenario, algo) -> [(seed, row)]
    for path in args.eval:
        data = read_eval(path)
        for row in data["rows"]:
            if "beta_minus" in row:
                found[data["scenario"], row["algo"]].append((row.get("seed", data.get("seed")), row))
    if not found:
        fail("no row with beta_minus (a model that blends: TARL, its ablations, SAC-Lattice) in " +
             ", ".join(map(str, args.eval)))
    keys = sorted(found, key=lambda k: (SCENARIOS.index(k[0]) if k[0] in SCENARIOS else 9,
                                        ORDER.index(k[1]) if k[1] in ORDER else 99, k[1]))
    lines = ["## 1 - beta (Sec. 5.5): the share of the base planner's action in the executed one", "",
             "| scenario | model | seed | test cases | collisions | all steps | last 3 s before a collision | "
             "last 1 s before a collision |", "|---|---|---|---|---|---|---|---|"]
    for sc, algo in keys:
        rows = sorted(found[sc, algo], key=lambda r: r[0])
        values = []
        for seed, row in rows:
            bm = row["beta_minus"]
            v = [bm["all_steps"], bm["3s_before_collision"], bm["1s_before_collision"]]
            values.append(v)
            cases = row.get("cases", [])
            lines.append(f"| {sc} | {name(algo)} | {seed} | {len(cases)} | {sum(c['outcome'] == 'collision' for c in cases)}"
                         f" | " + " | ".join(fmt(x) for x in v) + " |")
        if len(rows) > 1:
            lines.append(f"| {sc} | {name(algo)} | mean of {len(rows)} | | | "
                         + " | ".join(fmt(mean_of(col)) for col in zip(*values)) + " |")
        if algo == "tarl" and sc in PAPER_BETA_MINUS:
            lines.append(f"| {sc} | TARL, paper | | 10 x 200 | | " + " | ".join(f"{x:.3f}" for x in PAPER_BETA_MINUS[sc]) + " |")
    timing = [k for k in keys if any("timing_share" in row for _, row in found[k])]
    if timing:
        lines += ["", "## The timing taker's T: the share of steps at each T (beta(1) = 1, beta(2) = 0.5, "
                  f"beta(3) = {tarl.beta(3, omega=tarl.TimingConfig().omega):.3f}, beta(T >= 4) < 0.05)", "",
                  "| scenario | model | seed | T = 1 | T = 2-3 | T >= 4 | T = 1, last 3 s before a collision | "
                  "T = 2-3, last 3 s | T >= 4, last 3 s |", "|---|---|---|---|---|---|---|---|---|"]
        for sc, algo in timing:
            values = []
            for seed, row in sorted(found[sc, algo], key=lambda r: r[0]):
                share = row.get("timing_share") or {}
                v = grouped(share.get("all_steps")) + grouped(share.get("3s_before_collision"))
                values.append(v)
                lines.append(f"| {sc} | {name(algo)} | {seed} | " + " | ".join(fmt(x) for x in v) + " |")
            if len(values) > 1:
                lines.append(f"| {sc} | {name(algo)} | mean of {len(values)} | "
                             + " | ".join(fmt(mean_of(col)) for col in zip(*values)) + " |")
    lines += ["", "Paper: Sec. 5.5 (intersection 49.5 %, 65.7 %, 85.9 %; roundabout 66.3 %, 83.9 %, 87.2 %). "
              "1 - beta: the mean over the steps of every test case (all steps) or over the last 15 / 5 steps "
              "(3 s / 1 s at 0.2 s) of the cases that collided; '-': no collision."]
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
        print(f"wrote {args.out}", file=sys.stderr)
    return text


# ---- The safe-RL baselines' constraint: J_c and lambda over training --------------------------------


def read_constraint(path: Path) -> dict:
    """constraint_log.csv (baselines.py) -> arrays per column: step, J_c, lambda (CPO: cpo_case, trial)."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        if rows and not {"step", "J_c"} <= set(rows[0]):
            fail(f"{path} lacks the columns step, J_c: is it a baselines.py constraint_log.csv?")
        return {k: np.array([float(r[k]) for r in rows]) for k in (rows[0] if rows else ("step", "J_c"))}
    except (OSError, ValueError, TypeError) as e:
        fail(f"cannot read {path}: {e}")


def constraint(args):
    """J_c (the mean cost of the last 50 episodes) against the limit d, and lambda, over training steps; the
    mean over seeds with a min-max band. Also a markdown table of what lambda did, per run."""
    logs = defaultdict(dict)
    for path in sorted(args.runs.glob("*/constraint_log.csv")) if args.runs.is_dir() else []:
        m = RUN_NAME.match(path.parent.name)
        if m and m["scenario"] in SCENARIOS and m["budget"] is None:
            logs[m["scenario"], m["algo"]][int(m["seed"])] = read_constraint(path)
    logs = {k: {seed: log for seed, log in v.items() if len(log["step"])} for k, v in logs.items()}
    logs = {k: v for k, v in logs.items() if v}
    if not logs:
        fail(f"no SCENARIO-ALGO-sSEED/constraint_log.csv with an update in {args.runs}")
    d = baselines.SafeRLConfig.cost_limit
    scenarios = [s for s in SCENARIOS if any(sc == s for sc, _ in logs)]
    fig, axes = plt.subplots(2, len(scenarios), figsize=(6.5 * len(scenarios), 7), squeeze=False, sharex="col")
    lines = ["| scenario | model | seed | updates | J_c at the end | lambda: max | at the end | updates with lambda > 0 |",
             "|---|---|---|---|---|---|---|---|"]
    for col, scenario in enumerate(scenarios):
        end = max(int(log["step"].max()) for (sc, _), seeds in logs.items() if sc == scenario for log in seeds.values())
        x = np.linspace(0, end, 200)
        for algo in [a for a in ORDER if (scenario, a) in logs]:
            seeds = logs[scenario, algo]
            for row, key in enumerate(("J_c", "lambda")):
                have = [log for log in seeds.values() if key in log]
                if not have:
                    continue
                curves = np.array([np.where((x >= log["step"][0]) & (x <= log["step"][-1]), np.interp(x, log["step"], log[key]),
                                             np.nan) for log in have])  # each seed where it has updates
                mean, low, high = over_seeds(curves)
                axes[row, col].fill_between(x, low, high, color=COLORS[algo], alpha=0.18, linewidth=0)
                axes[row, col].plot(x, mean, color=COLORS[algo], lw=1.8, label=f"{name(algo)} ({len(have)} seed{'s' * (len(have) > 1)})")
            for seed, log in sorted(seeds.items()):
                lam = log.get("lambda")
                lines.append(f"| {scenario} | {name(algo)} | {seed} | {len(log['step'])} | {log['J_c'][-1]:.3f} | "
                             + (f"{lam.max():.3f} | {lam[-1]:.3f} | {np.mean(lam > 0):.2f} |" if lam is not None else "- | - | - |"))
        axes[0, col].axhline(d, color="k", ls="--", lw=1.2, label=f"the limit d = {d}")
        axes[0, col].set_title(f"{scenario.capitalize()} scenario")
        axes[0, col].set_ylabel("J_c: collisions per episode\n(last 50 episodes)")
        axes[1, col].set_ylabel("Lagrange multiplier lambda")
        axes[1, col].set_xlabel("training step (simulator steps)")
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right", frameon=False)
            ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0), useMathText=True)
    fig.suptitle("The safe-RL baselines' constraint over training (CPO has no multiplier)", fontsize=13)
    fig.tight_layout()
    save(fig, args.out)
    text = "\n".join(lines)
    print(text)
    return text


# ---- Command line ----------------------------------------------------------------------------------


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 2)[2])
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("training", help="Fig. 5: training curves from train_log.csv files")
    t.add_argument("--runs", type=Path, default=ROOT / "results" / "runs", help="folder of SCENARIO-ALGO-sSEED runs")
    t.add_argument("--out", type=Path, default=ROOT / "results" / "fig5_training.png")
    t.add_argument("--budget", help="draw the runs of another budget, named SCENARIO-ALGO-sSEED-BUDGET (500k)")
    t.add_argument("--bin", type=int, help="steps per bin (default: 5000, less for runs shorter than 100,000 steps)")
    t.add_argument("--algos", nargs="+", help="rows to draw, or 'all' (default: Table 3's learned rows and the two "
                   "ablations)")
    for command, help_ in (("case", "Fig. 6: one test case, step by step"),
                           ("failure", "Fig. 7: the first test case of an eval.json that ended in a collision")):
        c = sub.add_parser(command, help=help_)
        c.add_argument("--scenario", choices=SCENARIOS, default="roundabout")
        c.add_argument("--algo", choices=tuple(experiment.ROWS), default="tarl")
        c.add_argument("--load", type=Path, metavar="CKPT", help="ckpt.pt or policy.pt (not for --algo lattice-idm)")
        c.add_argument("--out", type=Path, help=f"PNG (default results/fig{6 if command == 'case' else 7}_SCENARIO.png)")
        c.add_argument("--window", type=float, default=120.0, help="side of the snapshots [m], centred on the "
                       "junction, moved to keep the ego inside")
        if command == "case":
            c.add_argument("--seed", type=int, default=0, help="the evaluation's seed (tarl.py --seed)")
            c.add_argument("--round", type=int, default=0)
            c.add_argument("--case", type=int, required=True)
            c.add_argument("--cases", type=int, default=200, help="test cases per round (tarl.py --eval-cases)")
        else:
            c.add_argument("--eval", type=Path, required=True, help="eval.json of the run (tarl.py)")
            c.add_argument("--pick", type=int, default=0, help="which collision, counted from 0 in the order of eval.json")
    k = sub.add_parser("constraint", help="J_c and lambda of the safe-RL rows over training, and a table")
    k.add_argument("--runs", type=Path, default=ROOT / "results" / "runs", help="folder of SCENARIO-ALGO-sSEED runs")
    k.add_argument("--out", type=Path, default=ROOT / "results" / "fig_constraint.png")
    b = sub.add_parser("beta", help="Sec. 5.5: 1 - beta and the timings, a markdown table")
    b.add_argument("--eval", type=Path, nargs="+", required=True)
    b.add_argument("--out", type=Path, help="also write the table here")
    return p.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    return {"training": training, "case": case, "failure": failure, "beta": beta, "constraint": constraint}[args.command](args)


if __name__ == "__main__":
    main()
