"""Videos of test cases: an animated GIF of one test case, every simulator step a frame, at real time.

    python bench/video.py --scenario roundabout --round 0 --case 3 \\
        --left tarl:results/runs/roundabout-tarl-s0/policy.pt --right lattice-idm \\
        --eval results/runs/roundabout-tarl-s0/eval.json --out results/video_roundabout.gif
    python bench/video.py --scenario intersection --case 3 --left tarl:runs/x/policy.pt \\
        --right tarl:runs/x/policy.pt:fixed=1 --out /tmp/tarl_vs_its_actor.gif

Test case --case of evaluation round --round (of the evaluation seeded --seed, as tarl.py --seed), played
exactly as experiment.play_round plays it (bench/figures.py's replay), by one driver (--left) or by two
side by side (--left, --right) on the same case. A DRIVER is ALGO[:CKPT][:TIMING]:
  ALGO    a row of Table 3 (tarl, sac, lattice-idm, ...: tarl.py --algo); lattice-idm takes no CKPT
  CKPT    its ckpt.pt or policy.pt (tarl.py's --load)
  TIMING  how the loaded actor's T is chosen, as tarl.py's --timing: learned, phased, random, fixed=T, cap=T,
          distilled=PATH (a student of bench/distillation.py)
e.g. tarl:results/runs/roundabout-tarl-s0/policy.pt, or tarl:...policy.pt:fixed=1 (TARL's actor alone).

Each side: the driver and its outcome; the scene from above (scene.py, as DrivingEnv.render() and Fig. 6
draw it: the ego in the colour of who drives, the actor, the planner or their blend by beta) with time,
speed, T and beta; under it a strip of beta (the actor's share of Eq. (12), bars in the ego's colour) and
T (line) over the whole episode, a cursor at the present step. One frame per simulator step (dt = 0.2 s,
200 ms a frame) and one more, the state the episode ended in, held --hold seconds; a side that ended
first holds its last state. With --eval (the run's eval.json) each side whose row is in it must start
from the recorded fingerprint and end in the recorded outcome, or nothing is written. GIFs: one palette
of --colors colours, unchanged pixels transparent (Pillow's optimize); with ffmpeg on PATH also an MP4.
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]
import experiment  # noqa: E402
import figures  # noqa: E402
import scene  # noqa: E402
import tarl  # noqa: E402
import world  # noqa: E402

TIMING_SPEC = re.compile(r"^(learned|phased|random|fixed|cap|rollout|distilled)(=.+)?$")  # tarl.py --timing's names
HEADER, STRIP = 22, 56  # [px] a side's title line above the view, the beta/T strip below it


def fail(message: str):
    raise SystemExit(f"video.py: {message}")


# ---- The drivers ------------------------------------------------------------------------------------


def parse_driver(spec: str, scenario: str, seed: int) -> argparse.Namespace:
    """ALGO[:CKPT][:TIMING] -> what figures.make_driver takes (algo, load, timing, scenario, seed), checked."""
    algo, _, rest = spec.partition(":")
    ckpt, _, timing = rest.rpartition(":")
    if not TIMING_SPEC.match(timing):  # no timing: all of it is the checkpoint's path
        ckpt, timing = rest, ""
    if algo not in experiment.ROWS:
        fail(f"{spec}: unknown algo {algo!r}; choose from {', '.join(experiment.ROWS)}")
    if algo == "lattice-idm" and (ckpt or timing):
        fail(f"{spec}: lattice-idm is the planner alone, it takes no checkpoint or timing")
    if algo != "lattice-idm" and not ckpt:
        fail(f"{spec}: {algo} needs its checkpoint, {algo}:CKPT (a ckpt.pt or policy.pt of tarl.py)")
    if timing and (error := experiment.timing_error(timing, algo)):  # as tarl.py --timing
        fail(f"{spec}: timing {error}")
    if ckpt and not Path(ckpt).is_file():
        fail(f"{spec}: checkpoint not found: {ckpt}")
    return argparse.Namespace(algo=algo, load=Path(ckpt) if ckpt else None, timing=timing or None, scenario=scenario,
                              seed=seed)


def check_against(eval_data: dict, side: argparse.Namespace, ep: dict, round_: int, case: int, path: Path):
    """The played case started and ended as the evaluation's (if its row is in eval.json and not re-timed)."""
    rows = [r for r in eval_data["rows"] if r.get("algo") == side.algo]
    if side.timing or not rows:
        figures.progress(f"  {side.algo}{' re-timed' if side.timing else ''}: not in {path}, not checked")
        return
    recorded = next((c for c in rows[0].get("cases", []) if (c["round"], c["case"]) == (round_, case)), None)
    if recorded is None:
        fail(f"{path} has no round {round_} case {case} of {side.algo}")
    if (ep["start"], ep["outcome"]) != (recorded["start"], recorded["outcome"]):
        fail(f"{side.algo} played round {round_} case {case} from start {ep['start']} to {ep['outcome']}, but {path} "
             f"recorded {recorded['start']} and {recorded['outcome']}: not the evaluated case or model")
    figures.progress(f"  {side.algo}: start {ep['start']} and {ep['outcome']} as in {path}")


# ---- The frames -------------------------------------------------------------------------------------


def outcome_text(ep: dict, dt: float) -> str:
    if ep["outcome"] == "arrival":
        return f"arrives, crossing time {ep['crossing_time']:.1f} s"
    return f"times out at {ep['steps'] * dt:.0f} s" if ep["outcome"] == "timeout" else f"collides at t = {ep['steps'] * dt:.1f} s"


def canvas_pixels(fig: Figure) -> np.ndarray:
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class Panel:
    """One side of the video: its title, a slot for the view (size x size px, framed) and the strip of beta
    and T over its episode, drawn once; frame(k) pastes step k's view into the slot and moves the cursor."""

    def __init__(self, ep: dict, title: str, size: int, dt: float, t_max: int, dpi: int = 100):
        self.size, self.steps, self.dt = size, ep["steps"], dt
        fig = Figure(figsize=(size / dpi, (HEADER + size + STRIP) / dpi), dpi=dpi, facecolor="white")
        h = fig.bbox.height
        text = fig.text(6 / size, 1 - 4 / h, title, ha="left", va="top", fontsize=9, fontweight="bold")
        while text.get_window_extent(FigureCanvasAgg(fig).get_renderer()).width > size - 12 and text.get_fontsize() > 6:
            text.set_fontsize(text.get_fontsize() - 0.5)  # a long title, smaller
        ax = fig.add_axes((30 / size, 16 / h, 1 - 60 / size, (STRIP - 22) / h))  # [px] room for the tick labels
        t, beta, T = np.arange(self.steps) * dt, np.asarray(ep["beta"], dtype=float), np.asarray(ep["T"], dtype=float)
        ax.bar(t, beta, width=dt, align="edge", color=[scene.ego_color(b) for b in beta], lw=0)
        ax.set_xlim(0, self.steps * dt)
        ax.set_ylim(0, 1.05)
        ax.set_yticks([0, 1])
        ax.set_ylabel("\u03b2", fontsize=9, rotation=0, labelpad=6, va="center")
        ax.xaxis.set_major_locator(MaxNLocator(8, steps=[1, 2, 5, 10]))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g} s"))
        ax.tick_params(labelsize=7, length=2, pad=1)
        if np.all(beta == beta[0]) and beta[0] in (0.0, 1.0):  # one driver throughout
            ax.text(0.5, 0.5, f"\u03b2 = {beta[0]:g} throughout: the {'planner' if beta[0] == 0 else 'actor'} alone drives",
                    transform=ax.transAxes, ha="center", va="center", fontsize=8, color="0.3",
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.85))
        if (T > 0).any():  # a timing: T of each step, on the right
            ax2 = ax.twinx()
            ax2.step(np.r_[t, self.steps * dt], np.r_[T, T[-1]], where="post", color=figures.TIMING, lw=1.0)
            ax2.set_ylim(0.5, t_max + 0.5)
            ax2.set_yticks([1, t_max])
            ax2.set_ylabel("T", fontsize=9, rotation=0, labelpad=4, va="center", color=figures.TIMING)
            ax2.tick_params(labelsize=7, length=2, pad=1, colors=figures.TIMING)
        self.image = canvas_pixels(fig)
        self.image[[HEADER - 1, HEADER + size], :] = self.image[HEADER:HEADER + size, [0, -1]] = 150  # the view's frame
        box = ax.get_window_extent()  # [px] from the bottom left
        self.x0, self.px_per_s = box.x0, box.width / (self.steps * dt)
        self.rows = slice(int(self.image.shape[0] - box.y1), int(self.image.shape[0] - box.y0))

    def frame(self, k: int, view: np.ndarray) -> np.ndarray:
        """Step k's frame (k = steps: the state the episode ended in; later: held), with the view pasted."""
        out = self.image.copy()
        out[HEADER:HEADER + self.size, 1:-1] = view[:, 1:-1]
        x = int(round(self.x0 + min(k, self.steps) * self.dt * self.px_per_s))
        out[self.rows, max(x - 1, 0):x + 1] = 30  # the cursor: the state shown
        return out


def legend(width: int, perception: float, dpi: int = 100) -> np.ndarray:
    """What the colours mean (perception: d_max [m]), and the strips, as wide as the video."""
    handles = scene.legend_handles(perception, short=True)
    ncol = 8 if width >= 900 else 4
    rows = -(-len(handles) // ncol)
    caption = textwrap.fill("strips: \u03b2, the actor's share of the executed action (Eq. (12); 1 - \u03b2 is the "
                            "planner's), in the ego's colour; T, the timing [steps]; the cursor: the step shown", width // 5)
    fig = Figure(figsize=(width / dpi, (6 + 15 * rows + 11 * (caption.count("\n") + 1)) / dpi), dpi=dpi, facecolor="white")
    fig.legend(handles=handles, loc="upper center", ncol=ncol, frameon=False, fontsize=7, handlelength=1.4,
               handletextpad=0.4, columnspacing=1.0, borderaxespad=0.1)
    fig.text(0.5, 2 / fig.bbox.height, caption, ha="center", va="bottom", fontsize=7, color="0.3")
    return canvas_pixels(fig)


# ---- Writing ------------------------------------------------------------------------------------------


def make_palette(image: Image.Image, colors: int) -> Image.Image:
    """A palette of `colors`: scene.py's own colours (the ego's at five betas, small on screen, would
    otherwise merge), the rest the image's most representative (median cut)."""
    rgb = lambda c: tuple(round(255 * x) for x in to_rgb(c))  # noqa: E731
    egos = [scene.ego_color(b) for b in (0.0, 0.25, 0.5, 0.75, 1.0)]
    keys = {rgb(c) for c in ("white", "black", "0.3", "0.6", scene.ROAD, scene.ROAD_EDGE, scene.NEAR, scene.NEAR_EDGE,
                             scene.FAR, scene.FAR_EDGE, scene.PLAN, figures.TIMING, *scene.GAME.values(), *egos,
                             *(tuple(0.5 * np.array(c)) for c in egos))}
    rest = image.quantize(max(colors - len(keys), 2), method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    table = [*keys, *np.reshape(rest.getpalette()[:3 * (colors - len(keys))], (-1, 3)).tolist()]
    palette = Image.new("P", (1, 1))
    palette.putpalette([v for c in table for v in c])
    return palette


def write_gif(frames, n: int, out: Path, dt: float, hold: float, colors: int) -> list[Image.Image]:
    """The frames (an iterable of n (H, W, 3) uint8 arrays) as a GIF of one palette, each shown dt [s], the last
    hold [s]; unchanged pixels are left transparent (Pillow's optimize). Returns the frames as written."""
    images, palette, t0 = [], None, time.time()
    for k, frame in enumerate(frames):
        image = Image.fromarray(frame)
        if palette is None:  # one palette for every frame: the first frame holds the strips and the legend
            palette = make_palette(image, colors)
        images.append(image.quantize(palette=palette, dither=Image.Dither.NONE))
        if (k + 1) % 50 == 0 or k + 1 == n:
            spent = time.time() - t0
            figures.progress(f"  frame {k + 1}/{n} [{spent:.0f} s, ETA {spent / (k + 1) * (n - k - 1):.0f} s]")
    durations = [round(1000 * dt)] * (n - 1) + [round(1000 * max(hold, dt))]  # [ms]
    images[0].save(out, save_all=True, append_images=images[1:], duration=durations, loop=0, optimize=True, disposal=1)
    print(f"wrote {out} ({n} frames, {out.stat().st_size / 1e6:.2f} MB)")
    return images


def write_mp4(images: list[Image.Image], out: Path, dt: float, hold: float):
    """The same frames as out.mp4 (H.264, 1 / dt frames per second, the last repeated for hold [s]), if ffmpeg is
    on PATH; else a line saying so."""
    ffmpeg = shutil.which("ffmpeg")
    if not ffmpeg:
        print("no ffmpeg on PATH: no MP4")
        return
    w, h = images[0].size
    proc = subprocess.Popen([ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
                             "-r", f"{1 / dt:g}", "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p",
                             str(out.with_suffix(".mp4"))], stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        for image in images + images[-1:] * max(0, round(hold / dt) - 1):
            proc.stdin.write(image.convert("RGB").tobytes())
        proc.stdin.close()
    except BrokenPipeError:  # ffmpeg stopped: its message follows
        pass
    error = proc.stderr.read().decode(errors="replace").strip().splitlines()
    print(f"wrote {out.with_suffix('.mp4')}" if proc.wait() == 0 else f"ffmpeg failed, no MP4: {(error or ['?'])[0]}")


def video(args) -> list[dict]:
    sides = [parse_driver(s, args.scenario, args.seed) for s in (args.left, args.right) if s]
    eval_data = figures.read_eval(args.eval) if args.eval else None
    if eval_data and (eval_data["scenario"], int(eval_data.get("seed", 0))) != (args.scenario, args.seed):
        fail(f"--eval {args.eval} is of the {eval_data['scenario']} with --seed {eval_data.get('seed', 0)}, "
             f"not --scenario {args.scenario} --seed {args.seed}")
    figures.torch_threads()
    cfg = world.EnvConfig(scenario=args.scenario)
    env = world.DrivingEnv(cfg)
    try:
        drivers = [figures.make_driver(side, env) for side in sides]  # the checkpoints, before any simulation
        episodes = figures.replay(env, [d for d, _ in drivers], args.seed, args.round, args.case)
    finally:
        env.close()
    if eval_data:
        for side, ep in zip(sides, episodes):
            check_against(eval_data, side, ep, args.round, args.case, args.eval)
    n = max(ep["steps"] for ep in episodes) + 1  # a frame per step, and the last state
    renderer = scene.Renderer(env.net_file, size=args.size)
    panels = [Panel(ep, f"{label}: {outcome_text(ep, cfg.dt)}", args.size, cfg.dt, tarl.TimingConfig().t_max)
              for (_, label), ep in zip(drivers, episodes)]
    key = legend(args.size * len(panels), cfg.perception)
    frames = (np.vstack([np.hstack([p.frame(k, renderer.frame(ep["frames"][min(k, ep["steps"])]))
                                    for p, ep in zip(panels, episodes)]), key]) for k in range(n))
    figures.progress(f"rendering {n} frames of round {args.round} case {args.case}")
    write_mp4(write_gif(frames, n, args.out, cfg.dt, args.hold, args.colors), args.out, cfg.dt, args.hold)
    return episodes


# ---- Command line ------------------------------------------------------------------------------------


class Help(argparse.RawDescriptionHelpFormatter, experiment.Help):
    """The text as written, each option's default (but None)."""


class Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, as every other error
        fail(message)


def parse_args(argv=None):
    p = Parser(description=__doc__.split("\n\n")[0], formatter_class=Help,
               epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--scenario", choices=figures.SCENARIOS, default="roundabout", help="the network (scenarios/)")
    p.add_argument("--left", required=True, metavar="DRIVER", help="ALGO[:CKPT][:TIMING], alone or on the left")
    p.add_argument("--right", metavar="DRIVER", help="ALGO[:CKPT][:TIMING] on the right, on the same case")
    p.add_argument("--seed", type=int, default=0, help="the evaluation's seed (tarl.py --seed)")
    p.add_argument("--round", type=int, default=0, help="the evaluation round, from 0")
    p.add_argument("--case", type=int, required=True, help="the test case of the round, from 0")
    p.add_argument("--cases", type=int, default=200, help="test cases per round (tarl.py --eval-cases)")
    p.add_argument("--eval", type=Path, help="the run's eval.json: check each side's start and outcome against it")
    p.add_argument("--out", type=Path, help="GIF (default results/video_SCENARIO.gif); an MP4 beside it with ffmpeg")
    p.add_argument("--size", type=int, default=480, help="a view's side [px] (120 m)")
    p.add_argument("--colors", type=int, default=64, help="the GIF's palette (2-255): fewer, a smaller file")
    p.add_argument("--hold", type=float, default=2.0, help="[s] the last frame (the episode's end) is shown this long")
    args = p.parse_args(argv)
    if args.round < 0 or args.case < 0:
        fail("--round and --case count from 0")
    if args.case >= args.cases:
        fail(f"--case {args.case} is beyond the round: it has --cases {args.cases} test cases (0-{args.cases - 1})")
    if not 2 <= args.colors <= 255 or args.size < 100 or args.hold < 0:
        fail("--colors is 2-255, --size at least 100 [px], --hold at least 0 [s]")
    args.out = args.out or ROOT / "results" / f"video_{args.scenario}.gif"
    if args.out.suffix.lower() != ".gif":
        fail(f"--out {args.out}: a .gif")
    if not args.out.parent.is_dir():
        fail(f"--out {args.out}: no folder {args.out.parent}")
    if args.eval and not args.eval.is_file():
        fail(f"--eval {args.eval}: no such file")
    return args


def main(argv=None):
    return video(parse_args(argv))


if __name__ == "__main__":
    main()
