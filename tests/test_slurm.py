"""bench/slurm.py, Table 3's grid as a Slurm array job (bench/table3.py --slurm), on a real Slurm: tiny cells run
and publish their own files alone, a cancelled task and one warned of its time limit resume from their checkpoints
(so does the same command after Slurm itself was stopped), --collect-only names what is not finished, bad input is
one line. The tests that need Slurm run wherever
Slurm is installed; without sbatch on PATH they skip with one line that says how to install it, and fail instead
where TARL_REQUIRE_SLURM=1 (.ci/run sets it). They never use a cluster that is already running (its queue is not
theirs): they start a single-node Slurm of their own on free ports for the session and stop it by its pids."""
import getpass
import os
import re
import shutil
import socket
import subprocess
import time
from argparse import Namespace

import pytest

import slurm  # noqa: E402
import table3  # noqa: E402

# SAC, 3,000 steps: the first 2,000 (before it learns) take seconds, the last 1,000 about 15 s on a busy core
CELLS = ["--algos", "sac", "--seeds", "0", "--steps", "3000", "--rounds", "1", "--cases", "2"]
BUSY = 600  # [s] the most a stretch of a cell may take on cores other work shares (a load of 7 on 2 cores: 4-5 min)


# A cluster of this one machine: auth/none and cred/none fit a single node; the project's job files depend on none of
# this (a real cluster has munge, its own partitions and limits). MinJobAge: a finished task stays in scontrol's view
# for the session (Slurm's default, 5 min, could drop a task that ended early before the last one ends).
SLURM_CONF = """ClusterName=tarl-test
SlurmctldHost={host}
SlurmctldPort={ctld_port}
SlurmdPort={d_port}
SlurmUser={user}
SlurmctldPidFile={d}/slurmctld.pid
SlurmdPidFile={d}/slurmd.pid
SlurmdSpoolDir={d}/slurmd
StateSaveLocation={d}/slurmctld
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
AuthType=auth/none
CredType=cred/none
JobAcctGatherType=jobacct_gather/none
MinJobAge=3600
NodeName={host} CPUs={cpus} State=UNKNOWN
PartitionName=debug Nodes={host} Default=YES MaxTime=INFINITE State=UP
"""


def nodes(*options: str) -> str:
    """sinfo's node lines (empty if no controller answers)."""
    return subprocess.run(["sinfo", "-h", *options], capture_output=True, text=True).stdout.strip()


def free_port() -> int:
    """A TCP port no one listens on now (the OS's choice)."""
    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def slurm_up(tmp_path_factory):
    """A single-node Slurm started here for the session on two free ports (SLURM_CONF points every Slurm command
    at it), stopped by its daemons' pids. No sbatch on PATH: skipped, or a failure where TARL_REQUIRE_SLURM=1."""
    if shutil.which("sbatch") is None:
        say = pytest.fail if os.environ.get("TARL_REQUIRE_SLURM") == "1" else pytest.skip
        say("Slurm is not installed (no sbatch on PATH): Debian's `apt-get install slurm-wlm` runs these tests")
    d = tmp_path_factory.mktemp("slurm")
    for spool in ("slurmd", "slurmctld"):
        (d / spool).mkdir()
    conf = d / "slurm.conf"
    conf.write_text(SLURM_CONF.format(host=socket.gethostname().split(".")[0], user=getpass.getuser(), d=d,
                                      cpus=os.cpu_count(), ctld_port=free_port(), d_port=free_port()))
    os.environ["SLURM_CONF"] = str(conf)  # sbatch, sinfo, scontrol and the tasks read it
    daemons = []
    for daemon in ("slurmctld", "slurmd"):
        with open(d / f"{daemon}.log", "w") as log:
            daemons.append(subprocess.Popen([daemon, "-D", "-f", str(conf)], stdout=log, stderr=subprocess.STDOUT))
    try:
        deadline = time.time() + 30  # its node idle within seconds
        while not nodes("-t", "idle") and time.time() < deadline and all(p.poll() is None for p in daemons):
            time.sleep(1)
        if not nodes("-t", "idle"):
            logs = {n: (d / f"{n}.log").read_text().strip().splitlines() for n in ("slurmctld", "slurmd")}
            pytest.fail("a single-node Slurm did not start: " + "; ".join(
                f"{n}: {lines[-1] if lines else 'no output'}" for n, lines in logs.items()))
        yield
    finally:
        for p in daemons:  # SIGKILL too: slurmd waiting for its controller ignores SIGTERM
            p.terminate()
        for p in daemons:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        os.environ.pop("SLURM_CONF")


@pytest.fixture
def cluster(slurm_up):
    """A running Slurm; the array jobs a test submits are cancelled after it."""
    jobs = []
    yield jobs
    if jobs:
        subprocess.run(["scancel", *jobs], capture_output=True)


def submit(argv, capsys, jobs) -> str:
    """slurm.py --submit; the array job's id."""
    slurm.main([*argv, "--submit"])
    jobs.append(re.search(r"submitted array job (\d+)", capsys.readouterr().out)[1])
    return jobs[-1]


def states(job: str) -> dict:
    """{array task: (its state, its restarts)}, from scontrol: no accounting database needed. Tasks still pending
    together are one record (ArrayTaskId=0-1) and not in it yet."""
    out = subprocess.run(["scontrol", "-o", "show", "job", job], capture_output=True, text=True).stdout
    return {int(task): (state, int(restarts)) for task, state, restarts in
            re.findall(r"ArrayTaskId=(\d+) .*?JobState=(\w+) .*?Restarts=(\d+)", out)}


def completed(*tasks: str) -> bool:
    """Have these array tasks (JOB_TASK) completed? A task that ended otherwise fails the test at once."""
    ended = [states(job).get(int(task), ("PENDING",))[0] for job, task in (t.split("_") for t in tasks)]
    assert not set(ended) - {"PENDING", "CONFIGURING", "RUNNING", "COMPLETING", "COMPLETED"}, ended
    return set(ended) == {"COMPLETED"}


def wait_for(condition, what: str, seconds: float = 120):
    """Poll `condition` every second; fail after `seconds`, never wait forever."""
    deadline = time.time() + seconds
    while not condition():
        assert time.time() < deadline, f"waited {seconds} s for {what}"
        time.sleep(1)


def test_an_array_of_two_cells_runs_and_its_stopped_tasks_resume_from_their_checkpoints(tmp_path, capsys, cluster):
    """A 2-task array: once both cells train, task 0 gets the time limit's warning (USR1 to its main process, as
    `--signal=B:USR1@...` sends it): its cell saves and the task requeues itself. Task 1 is cancelled (SIGTERM to all
    its processes, as scancel, a time limit and a pre-emption send): its cell saves, and its log says to submit the
    same command again. Meanwhile --collect-only names both cells, unfinished, and the requeued task, pending. The
    same command submitted again resumes the cancelled cell; the requeued task and its twin in the new job share the
    other cell: one resumes it, the other ends at once. Both cells finish where they stopped and publish their own
    files (no table: --collect-only builds it, its header from the cells' eval.json)."""
    dirs = ["--work", str(tmp_path / "work"), "--results", str(tmp_path / "results")]
    job = submit(CELLS + dirs, capsys, cluster)
    logs = {s: tmp_path / "work" / f"{s}-sac-s0-3k" / "log.txt" for s in ("intersection", "roundabout")}
    wait_for(lambda: all(log.exists() and "step    2000/3000" in log.read_text() for log in logs.values()),
             "both cells to train", BUSY)
    subprocess.run(["scancel", "--batch", "--signal=USR1", f"{job}_0"], check=True)
    subprocess.run(["scancel", f"{job}_1"], check=True)
    wait_for(lambda: states(job) == {0: ("PENDING", 1), 1: ("CANCELLED", 0)}, "task 0 requeued, task 1 cancelled")
    wait_for(lambda: all("# on Slurm, this cell resumes" in log.read_text() for log in logs.values()),
             "both tasks to say how their cells resume")
    assert "submit the same command again" in logs["roundabout"].read_text()
    assert "its task requeues itself and resumes it" in logs["intersection"].read_text()
    slurm.main([*CELLS, *dirs, "--collect-only"])
    err = capsys.readouterr().err
    assert "not in the table: 2 cell(s) started in " in err and all(f"{s}-sac-s0-3k" in err for s in logs), err
    assert f"in Slurm's queue (squeue), tasks of {tmp_path}/work/grid.sbatch: 1 pending ({job}_0)" in err, err
    (tmp_path / "results" / "table3.md").unlink()  # its table of no cell: no task writes one again
    # Slurm holds a requeued task for 2 min; start it now, a second after its end (slurmd refuses it in that second)
    time.sleep(2)
    subprocess.run(["scontrol", "update", f"JobId={job}_0", "StartTime=now"], check=True)
    again = submit(CELLS + dirs, capsys, cluster)  # the same command: both cells, neither finished yet
    wait_for(lambda: completed(f"{job}_0", f"{again}_0", f"{again}_1"), "both cells to finish", BUSY)
    for scenario, log in logs.items():
        text = log.read_text()
        stopped = re.search(r"interrupted at step (\d+): saving", text)
        assert stopped and int(stopped[1]) >= 2000, text
        assert f"training sac on the {scenario} from step {stopped[1]} to 3000" in text, text  # not from step 0
        assert text.count("UTC: start, 1 thread(s)") == 2 and "UTC: finished after" in text, text
        assert (tmp_path / "results" / "runs" / log.parent.name / "eval.json").exists()
    assert not (tmp_path / "results" / "table3.md").exists()  # a task publishes its own files alone
    twins = [(tmp_path / "work" / f"slurm-{task}.out").read_text() for task in (f"{job}_0", f"{again}_0")]
    assert f"requeueing task {job}_0" in twins[0], twins
    assert [sum(out.count(word) for out in twins) for word in ("--resume", "done or run by another task")] == [1, 1]
    slurm.main([*CELLS, *dirs, "--collect-only"])
    out, err = capsys.readouterr()
    assert out.count("| SAC (") == 2 and "each seed's mean over 1 round x 2 test cases;" in out and not err, err


def test_bad_input_is_one_line_before_any_work(tmp_path, cluster):
    """An unknown partition and an array over no unfinished cell: one line each, nothing submitted or written."""
    dirs = ["--work", str(tmp_path / "work"), "--results", str(tmp_path / "results")]
    with pytest.raises(SystemExit, match=r"^--partition no-such-partition: not a partition of this cluster \("):
        slurm.main([*CELLS, *dirs, "--partition", "no-such-partition", "--submit"])
    for scenario in ("intersection", "roundabout"):
        (tmp_path / "results" / "runs" / f"{scenario}-sac-s0-3k").mkdir(parents=True)
        (tmp_path / "results" / "runs" / f"{scenario}-sac-s0-3k" / "eval.json").write_text("{}")
    with pytest.raises(SystemExit, match=r"^no unfinished cell: the 2 selected have their eval.json in "):
        slurm.main([*CELLS, *dirs, "--submit"])
    assert not (tmp_path / "work").exists()


def test_without_sbatch_it_says_so_in_one_line(tmp_path, monkeypatch):
    """No Slurm here: one line, nothing written."""
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SystemExit, match=r"^no sbatch on PATH: run this on a Slurm cluster's login node$"):
        slurm.main([*CELLS, "--work", str(tmp_path / "work"), "--submit"])
    assert not (tmp_path / "work").exists()


def test_what_does_not_go_with_slurm_says_why_in_one_line_before_any_work(tmp_path, capsys):
    """--commit, --threads and --jobs belong to a grid run here: with --slurm each is one line that says why; Slurm's
    own options without --slurm, one line too. Nothing written."""
    dirs = ["--work", str(tmp_path / "work"), "--results", str(tmp_path / "results")]
    for flag, why in (("--commit", "a Slurm task commits nothing; once the tasks are done, --collect-only builds "
                                   "the table: look, and commit it yourself"),
                      ("--threads 2", "a task's threads are its CPUs, --cpus-per-task"),
                      ("--jobs 2", "the cluster runs the tasks, one per cell")):
        with pytest.raises(SystemExit):
            slurm.main([*CELLS, *dirs, *flag.split(), "--submit"])
        err = capsys.readouterr().err
        assert err.startswith(f"bench/table3.py: {flag.split()[0]} does not go with --slurm: {why}"), err
        assert err.count("\n") == 1, err
    with pytest.raises(SystemExit):
        table3.main([*CELLS, *dirs, "--time", "4:00:00"])
    assert capsys.readouterr().err == "bench/table3.py: --time: Slurm's, with --slurm\n"
    assert not (tmp_path / "work").exists()


def test_after_slurm_was_stopped_the_same_command_skips_finished_cells_and_resumes_started_ones(tmp_path, capsys,
                                                                                                 slurm_up):
    """Slurm stopped between two working days, its tasks gone with it, then started again: the same command queues
    the unfinished cells alone, and a started cell's task resumes it from its ckpt.pt (--resume in its command)."""
    dirs = ["--work", str(tmp_path / "work"), "--results", str(tmp_path / "results")]
    (tmp_path / "results" / "runs" / "intersection-sac-s0-3k").mkdir(parents=True)
    (tmp_path / "results" / "runs" / "intersection-sac-s0-3k" / "eval.json").write_text("{}")  # finished
    (tmp_path / "work" / "roundabout-sac-s0-3k").mkdir(parents=True)
    (tmp_path / "work" / "roundabout-sac-s0-3k" / "ckpt.pt").write_bytes(b"")  # started
    slurm.main([*CELLS, *dirs, "--write", str(tmp_path / "again.sbatch")])
    assert capsys.readouterr().out.startswith(f"wrote {tmp_path / 'again.sbatch'}: 1 array task(s)")
    text = (tmp_path / "again.sbatch").read_text()
    assert '  "--scenarios roundabout --algos sac --seeds 0"' in text.splitlines() and "intersection" not in text
    p = table3.parser()
    task = table3.settle(p, p.parse_args(["--slurm", "--task", *CELLS, "--scenarios", "roundabout", *dirs]))
    assert table3.command("roundabout", "sac", 0, task, 1)[-1] == "--resume"


def test_the_job_file_has_the_command_lines_options_and_no_cluster_of_its_own(tmp_path):
    """CPUs, time limit and partition as given; no partition line without one (the cluster's default); requeued,
    warned before its limit; one task per cell."""
    args = Namespace(steps=3000, step_one=None, rounds=1, cases=2, work=tmp_path, results=tmp_path, cpus_per_task=2,
                     time="1-00:00", partition=None)
    todo = [("intersection", "sac", 0), ("roundabout", "cpo", 2)]
    text = slurm.job_file(todo, args)
    for line in ("#SBATCH --array=0-1", "#SBATCH --cpus-per-task=2", "#SBATCH --time=1-00:00", "#SBATCH --requeue",
                 f"#SBATCH --signal=B:USR1@{slurm.WARN}", '  "--scenarios roundabout --algos cpo --seeds 2"'):
        assert line in text.splitlines(), text
    assert "--partition" not in text
    assert (f"bench/table3.py --slurm --task ${{CELLS[$SLURM_ARRAY_TASK_ID]}} --steps 3000 --rounds 1 --cases 2 "
            f"--work {tmp_path} --results {tmp_path}") in text
    assert "#SBATCH --partition=gpu" in slurm.job_file(todo, Namespace(**{**vars(args), "partition": "gpu"}))
    assert [slurm.seconds(t) for t in ("90", "1:30", "2:00:00", "1-2", "1-00:00:30", "2h")] == [
        5400, 90, 7200, 93600, 86430, None]
