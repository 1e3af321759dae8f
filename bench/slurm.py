"""Table 3's grid on a Slurm cluster: one array task per unfinished cell, each resumable (bench/table3.py's cells).

    python bench/slurm.py --submit                         # every unfinished cell of the grid, 1 CPU and 2 h each
    python bench/slurm.py --seeds 0 --steps 500000 --time 4:00:00 --submit   # the paper's budget: 1.7-3 h a cell
    python bench/slurm.py --algos tarl sac --seeds 0       # print the job file
    python bench/slurm.py --write grid.sbatch              # write it, to read or to sbatch with options of your own
    python bench/slurm.py --collect                        # once the tasks are done: results/table3.md

Run it on the cluster's login node from the repository, with the python that has the requirements: the job file
names that python and this folder, which the compute nodes must see (a shared disk, as the cells' run directories
and results/ are). Each task runs its cell's own command (table3.py's, `--resume` where the run directory has a
ckpt.pt, 1 torch thread per CPU of the task) and, when the cell finishes, copies its files to results/runs/CELL
as table3.py does; it never commits: collect, look and commit yourself.

A stopped task loses less than a checkpoint interval (tarl.TrainConfig.checkpoint_every):
- scancel, a time limit reached, a pre-emption: Slurm sends SIGTERM to every process of the task, then SIGKILL
  after the cluster's KillWait (or pre-emption GraceTime); the cell saves its checkpoint on SIGTERM. A pre-empted
  task is requeued by Slurm (`--requeue`); a cancelled one resumes when you submit again.
- the time limit, ahead: `--signal=B:USR1@360` warns the task (its main process alone) 6 min before its limit
  (Slurm may warn up to a minute earlier); it stops the cell, which saves within 5 min (table3.SAVE_WAIT), and
  requeues itself (`scontrol requeue`): the task starts again later (Slurm holds a requeued job a while, 2 min by
  default) and resumes the cell. So a cell longer than --time still ends, in several stretches.
"""
import argparse
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from table3 import (ABLATIONS, ROOT, RUN, SAVE_WAIT, SCENARIOS, STEPS, cell_name, cells, claim, collect,  # noqa: E402
                    command, publish, stamp)
import experiment  # noqa: E402  (table3 puts the repository on sys.path)

WARN = SAVE_WAIT + 60  # [s] the time limit's warning: the cell's time to save, and a minute to requeue the task


def seconds(limit: str) -> int | None:
    """A time limit in Slurm's formats (sbatch --time: M, M:S, H:M:S, D-H, D-H:M, D-H:M:S) in seconds, else None."""
    match = re.fullmatch(r"(?:(\d+)-)?(\d+(?::\d+){0,2})", limit)
    if not match:
        return None
    parts = [int(x) for x in match[2].split(":")]
    units = (3600, 60, 1) if match[1] else {1: (60,), 2: (60, 1), 3: (3600, 60, 1)}[len(parts)]
    return int(match[1] or 0) * 86400 + sum(p * u for p, u in zip(parts, units))


def check_slurm(partition: str | None):
    """Slurm's commands are here and the partition, if one is given, is the cluster's (else the cluster's default)."""
    if shutil.which("sbatch") is None:
        raise SystemExit("no sbatch on PATH: run this on a Slurm cluster's login node")
    if partition is not None:
        known = subprocess.run(["sinfo", "-h", "-o", "%R"], capture_output=True, text=True).stdout.split()
        if partition not in known:
            raise SystemExit(f"--partition {partition}: not a partition of this cluster ({', '.join(known) or 'none'})")


def job_file(todo: list, args) -> str:
    """The sbatch array job: task i runs cell todo[i] through this module's --task (the cell's own command)."""
    keep = [f"--steps {args.steps}", f"--rounds {args.rounds}", f"--cases {args.cases}",
            f"--work {shlex.quote(str(args.work))}", f"--results {shlex.quote(str(args.results))}"]
    keep += [f"--step-one {args.step_one}"] * (args.step_one is not None)
    return "\n".join([
        "#!/bin/bash",
        "# Table 3 cells as a Slurm array job, written by bench/slurm.py: one task per cell of CELLS, resumable.",
        "#SBATCH --job-name=tarl-grid",
        f"#SBATCH --array=0-{len(todo) - 1}",
        f"#SBATCH --cpus-per-task={args.cpus_per_task}",  # the cell's torch threads and evaluation workers
        f"#SBATCH --time={args.time}",
        *[f"#SBATCH --partition={args.partition}"] * (args.partition is not None),
        "# pre-empted: back in the queue; warned before the time limit: the cell saves, the task requeues itself",
        "#SBATCH --requeue",
        f"#SBATCH --signal=B:USR1@{WARN}",
        "#SBATCH --open-mode=append",  # a requeued task adds to its output file
        f"#SBATCH --output={args.work}/slurm-%A_%a.out",
        "CELLS=(",
        *[f'  "--scenarios {scenario} --algos {algo} --seeds {seed}"' for scenario, algo, seed in todo],
        ")",
        f"cd {shlex.quote(str(ROOT))}",
        f"exec {shlex.quote(sys.executable)} bench/slurm.py --task ${{CELLS[$SLURM_ARRAY_TASK_ID]}} {' '.join(keep)}",
        ""])


def submit(path: Path) -> str:
    """sbatch the job file; its job id."""
    done = subprocess.run(["sbatch", "--parsable", str(path)], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"sbatch {path}: {' '.join(done.stderr.split())}")
    return done.stdout.strip().split(";")[0]


def run_task(cell: tuple, args):
    """One array task: the cell's own command, resumed from its ckpt.pt if it has one, its output in the cell's
    log.txt between the grid's stamps (table3.wall_times); published to results/runs when it finishes. Slurm's kill
    reaches the cell too, which saves: this process waits for it. The warning (USR1) reaches this process alone: it
    stops the cell and, once the cell has saved, requeues the task."""
    name = cell_name(*cell, args.steps, args.step_one)
    task = "_".join(os.environ.get(key, "?") for key in ("SLURM_ARRAY_JOB_ID", "SLURM_ARRAY_TASK_ID"))
    if (claimed := claim(cell, args)) is None:
        return print(f"{name}: done or run by another task", flush=True)
    out, _lock = claimed  # held until this task ends
    threads = int(os.environ.get("SLURM_CPUS_PER_TASK", 1))  # --cpus-per-task, also one given to sbatch itself
    cmd = command(*cell, args, threads)
    beside = f"beside: unknown (Slurm task {task} on {socket.gethostname()})"
    with open(out / "log.txt", "a") as log:
        stamp(log, f"start, {threads} thread(s), {beside}")
        start, stops = time.time(), []
        cell_proc = subprocess.Popen([sys.executable, *cmd[1:]], stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
        print(f"{name}: {' '.join(cmd)}", flush=True)

        def warned(signum, frame):  # the time limit ahead: stop the cell (it saves), kill it if it takes too long
            if "warned" in stops:  # once: a second SIGTERM would cut the cell's save short
                return
            stops.append("warned")
            cell_proc.terminate()
            timer = threading.Timer(SAVE_WAIT, cell_proc.kill)
            timer.daemon = True  # never keeps this task alive
            timer.start()
        signal.signal(signal.SIGUSR1, warned)
        signal.signal(signal.SIGTERM, lambda *_: stops.append("killed"))  # the cell has it too and saves
        code = cell_proc.wait()
        how = "finished" if code == 0 else "interrupted" if stops else "FAILED"
        stamp(log, f"{how} after {(time.time() - start) / 60:.1f} min, exit code {code}, {beside}")
    print(f"{name}: {how}, exit code {code} (its log: {out / 'log.txt'})", flush=True)
    if code == 0:
        return publish(*cell, args)
    if "warned" in stops:
        print(f"{name}: saved; requeueing task {task}, which resumes the cell when it starts again", flush=True)
        done = subprocess.run(["scontrol", "requeue", task], capture_output=True, text=True)  # Slurm ends this task
        if done.returncode != 0:
            raise SystemExit(f"{name}: could not requeue ({' '.join(done.stderr.split())}): submit again to resume it")
        return
    raise SystemExit(code)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algos", nargs="+", default=list(RUN + ABLATIONS), choices=RUN + ABLATIONS)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    p.add_argument("--steps", type=int, default=STEPS, help="training steps of every learned row (as table3.py's)")
    p.add_argument("--step-one", type=int, help="steps of Alg. 1's step 1 in every cell (as table3.py's)")
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--cases", type=int, default=200)
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "grid", help="the cells' run directories and the "
                   "tasks' output files (slurm-JOB_TASK.out), on a disk the compute nodes share")
    p.add_argument("--results", type=Path, default=ROOT / "results")
    p.add_argument("--cpus-per-task", type=int, default=1, help="each task's CPUs, the cell's torch threads and "
                   "evaluation workers: one-thread cells side by side use the cores best")
    p.add_argument("--time", default="2:00:00", help="each task's time limit (sbatch --time; default 2 h: a "
                   "10^5-step cell at one thread with margin; a 5 x 10^5-step one takes 1.7-3.0 h). A longer cell is "
                   "warned, saves, and its task requeued resumes it")
    p.add_argument("--partition", help="the cluster's partition (default: the cluster's default partition)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--submit", action="store_true", help="submit the array job (its file: WORK/grid.sbatch)")
    what.add_argument("--write", type=Path, metavar="FILE", help="write the array job's file (to sbatch yourself)")
    what.add_argument("--collect", action="store_true", help="rebuild results/table3.md from the finished cells")
    what.add_argument("--task", action="store_true", help="run the one selected cell as an array task (the job "
                      "file's command)")
    args = p.parse_args(argv)
    args.work, args.results, args.commit, args.readme = args.work.resolve(), args.results.resolve(), False, False
    if args.step_one is not None and not 0 < args.step_one < args.steps:
        p.error("--step-one must be above 0 and below --steps")
    if args.step_one is not None and (plain := [a for a in args.algos if not experiment.ROWS[a].step_one]):
        p.error(f"--step-one: {', '.join(plain)} have no step 1")
    if args.cpus_per_task < 1:
        p.error("--cpus-per-task must be at least 1")
    if (limit := seconds(args.time)) is None or limit < 2 * WARN:
        p.error(f"--time {args.time}: give a Slurm time limit (M, H:M:S, D-H:M, ...) of at least {2 * WARN // 60} "
                f"min: a task is warned {WARN // 60} min before its limit to save and requeue itself")
    if args.collect:
        return print(collect(args))
    selected = cells(args.algos, args.seeds, args.scenarios)
    if args.task:
        if len(selected) != 1:
            p.error("--task runs one cell: give one scenario, algo and seed")
        return run_task(selected[0], args)
    check_slurm(args.partition)
    todo = [c for c in selected
            if not (args.results / "runs" / cell_name(*c, args.steps, args.step_one) / "eval.json").exists()]
    if not todo:
        raise SystemExit(f"no unfinished cell: the {len(selected)} selected have their eval.json in "
                         f"{args.results / 'runs'}; nothing to submit")
    args.work.mkdir(parents=True, exist_ok=True)  # Slurm writes the tasks' output files there
    if not (args.submit or args.write):
        return print(job_file(todo, args), end="")
    path = args.write or args.work / "grid.sbatch"
    path.write_text(job_file(todo, args))
    if args.write:
        return print(f"wrote {path}: {len(todo)} array task(s), one per unfinished cell; sbatch {path} submits them")
    job = submit(path)
    print(f"submitted array job {job}: {len(todo)} task(s), one per unfinished cell; their output: "
          f"{args.work}/slurm-{job}_TASK.out, their cells' logs: {args.work}/CELL/log.txt. Once they are done: "
          f"python bench/slurm.py --collect")


if __name__ == "__main__":
    main()
