"""Table 3's grid on a Slurm cluster, behind `python bench/table3.py --slurm`: one array task per unfinished cell,
each resumable. `python bench/slurm.py ARGS` is `python bench/table3.py --slurm ARGS`; the options (the grid's,
declared once for every path to a cell, and Slurm's): `python bench/table3.py --help`.

    python bench/table3.py --slurm --submit               # every unfinished cell of the grid, 1 CPU and 2 h each
    python bench/table3.py --slurm --seeds 0 --steps 500000 --time 4:00:00 --submit   # the paper's budget: 1.7-3 h
    python bench/table3.py --slurm --algos tarl sac --seeds 0     # print the job file
    python bench/table3.py --slurm --write grid.sbatch    # write it, to read or to sbatch with options of your own
    python bench/table3.py --collect-only                 # the table, once; it names the cells not finished yet
    python bench/table3.py --slurm --algos sac --seeds 0 --steps 3000 --rounds 1 --cases 10 --submit   # a trial

Run it on the cluster's login node from the repository, with the python that has the requirements: the job file
names that python and this folder, which the compute nodes must see (a shared disk, as the cells' run directories
and results/ are). Each task runs its cell's own command (table3.py's, `--resume` where the run directory has a
ckpt.pt, 1 torch thread per CPU of the task) and, when the cell finishes, copies the cell's own files to
results/runs/CELL, nothing else: no table (results/table3.md is tracked, and rewriting it would record every later
cell's code as COMMIT-dirty) and no commit (--commit, --threads and --jobs are refused with --slurm). Once the tasks
are done, --collect-only builds the table; look, and commit yourself. A trial (other than Table 3's 10 rounds x 200
cases) goes to runs/trial/, not results/ (bench/table3.py's docstring).

A stopped task loses less than a checkpoint interval (tarl.TrainConfig.checkpoint_every):
- scancel, a time limit reached, a pre-emption: Slurm sends SIGTERM to every process of the task, then SIGKILL
  after the cluster's KillWait (or pre-emption GraceTime); the cell saves its checkpoint on SIGTERM. A pre-empted
  task is requeued by Slurm (`--requeue`); a cancelled one resumes when you submit the same command again (its
  log.txt says so, below tarl.py's own "--resume" line, which is for a cell run by hand).
- the time limit, ahead: `--signal=B:USR1@360` warns the task (its main process alone) 6 min before its limit
  (Slurm may warn up to a minute earlier); it stops the cell, which saves within 5 min (table3.SAVE_WAIT), and
  requeues itself (`scontrol requeue`): the task starts again later (Slurm holds a requeued job a while, 2 min by
  default) and resumes the cell. So a cell longer than --time still ends, in several stretches.
- Slurm itself gone (a reboot, its daemons stopped between two working days): start it again and submit the same
  command. Finished cells (their eval.json in results/runs) are not submitted, started ones resume from their
  ckpt.pt; a task that Slurm recovers and requeues by itself beside them finds its cell taken (the run directory's
  lock) or done, and ends at once.
"""
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
import table3  # noqa: E402
from table3 import ROOT, SAVE_WAIT, cell_name, cells, claim, command, done, publish, stamp  # noqa: E402

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


def grid_flags(args) -> str:
    """The grid's options that every cell of the job shares, as table3.py reads them."""
    flags = [f"--steps {args.steps}", f"--rounds {args.rounds}", f"--cases {args.cases}",
             f"--work {shlex.quote(str(args.work))}", f"--results {shlex.quote(str(args.results))}"]
    return " ".join(flags + [f"--step-one {args.step_one}"] * (args.step_one is not None))


def cell_flags(scenario, algo, seed) -> str:
    return f"--scenarios {scenario} --algos {algo} --seeds {seed}"


def job_file(todo: list, args) -> str:
    """The sbatch array job: task i runs cell todo[i] through table3.py's --slurm --task (the cell's own command)."""
    return "\n".join([
        "#!/bin/bash",
        "# Table 3 cells as a Slurm array job, by bench/table3.py --slurm: a task per cell of CELLS, each resumable.",
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
        *[f'  "{cell_flags(*cell)}"' for cell in todo],
        ")",
        f"cd {shlex.quote(str(ROOT))}",
        f"exec {shlex.quote(sys.executable)} bench/table3.py --slurm --task ${{CELLS[$SLURM_ARRAY_TASK_ID]}} "
        f"{grid_flags(args)}",
        ""])


def submit(path: Path) -> str:
    """sbatch the job file; its job id."""
    done = subprocess.run(["sbatch", "--parsable", str(path)], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"sbatch {path}: {' '.join(done.stderr.split())}")
    return done.stdout.strip().split(";")[0]


def queued(work: Path) -> dict[str, list[str]]:
    """The array tasks of WORK/grid.sbatch (the job file --submit writes) still in Slurm's queue, by state: {"PENDING":
    ["12_3", ...], "RUNNING": [...]}; {} where this work directory was never submitted or no squeue answers."""
    job = work / "grid.sbatch"
    if not job.exists() or shutil.which("squeue") is None:
        return {}
    try:
        lines = subprocess.run(["squeue", "-h", "-r", "-o", "%i|%T|%o"], capture_output=True, text=True,
                               timeout=30).stdout.splitlines()
    except subprocess.TimeoutExpired:
        return {}
    tasks = {}
    for task, state, script in (line.split("|", 2) for line in lines if line.count("|") >= 2):
        if script == str(job):
            tasks.setdefault(state, []).append(task)
    return tasks


def run_task(cell: tuple, args):
    """One array task: the cell's own command, resumed from its ckpt.pt if it has one, its output in the cell's
    log.txt between the grid's stamps (table3.wall_times); its files published to results/runs when it finishes.
    Slurm's kill reaches the cell too, which saves: this process waits for it, and writes in the log how it resumes.
    The warning (USR1) reaches this process alone: it stops the cell and, once the cell has saved, requeues the task."""
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
        if how == "interrupted":  # tarl.py's line above says --resume: on Slurm, the queue resumes the cell
            again = ("its task requeues itself and resumes it" if "warned" in stops else
                     "unless Slurm requeues its task (as after a pre-emption), submit the same command again: the "
                     "grid's, or this cell's alone: python bench/table3.py --slurm "
                     f"{cell_flags(*cell)} {grid_flags(args)} --submit")
            log.write(f"# on Slurm, this cell resumes from its checkpoint: {again}\n")
    print(f"{name}: {how}, exit code {code} (its log: {out / 'log.txt'})", flush=True)
    if code == 0:
        return publish(*cell, args)  # its own files: no table, no commit
    if "warned" in stops:
        print(f"{name}: saved; requeueing task {task}, which resumes the cell when it starts again", flush=True)
        before = len(stops)
        done = subprocess.run(["scontrol", "requeue", task], capture_output=True, text=True)  # Slurm ends this task
        if done.returncode != 0 and "killed" not in stops[before:]:  # killed now: requeued, Slurm ends this task
            why = " ".join(done.stderr.split()) or f"exit code {done.returncode}"
            raise SystemExit(f"{name}: could not requeue ({why}): submit the same command again to resume it")
        return
    raise SystemExit(code)


def run(p, args):
    """table3.py --slurm, its command line parsed and checked (table3.settle): the unfinished cells' array job
    (printed, written or submitted), or --task's one cell. Bad input is one line, before any work."""
    if args.cpus_per_task < 1:
        p.error("--cpus-per-task must be at least 1")
    if (limit := seconds(args.time)) is None or limit < 2 * WARN:
        p.error(f"--time {args.time}: give a Slurm time limit (M, H:M:S, D-H:M, ...) of at least {2 * WARN // 60} "
                f"min: a task is warned {WARN // 60} min before its limit to save and requeue itself")
    selected = cells(args.algos, args.seeds, args.scenarios)
    if args.task:
        if len(selected) != 1:
            p.error("--task runs one cell: give one scenario, algo and seed")
        return run_task(selected[0], args)
    check_slurm(args.partition)
    todo = [c for c in selected if not done(c, args)]
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
          f"{table3.collect_command(args)}")


def main(argv=None):
    """`python bench/slurm.py ARGS`: `python bench/table3.py --slurm ARGS`."""
    return table3.main(["--slurm", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    main()
