"""bench/slurm.py, Table 3's grid as a Slurm array job, on a real Slurm: tiny cells run, a cancelled task and one
warned of its time limit resume from their checkpoints, bad input is one line. The tests that need Slurm run wherever
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

# SAC, 3,000 steps: the first 2,000 (before it learns) take seconds, the last 1,000 about 15 s on a busy core
CELLS = ["--algos", "sac", "--seeds", "0", "--steps", "3000", "--rounds", "1", "--cases", "2"]


# A cluster of this one machine: auth/none and cred/none fit a single node; the project's job files depend on none of
# this (a real cluster has munge, its own partitions and limits).
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
    its processes, as scancel, a time limit and a pre-emption send): its cell saves, and submitting again resumes it.
    Both cells finish where they stopped and are published to the results; --collect tables them."""
    dirs = ["--work", str(tmp_path / "work"), "--results", str(tmp_path / "results")]
    job = submit(CELLS + dirs, capsys, cluster)
    logs = {s: tmp_path / "work" / f"{s}-sac-s0-3k" / "log.txt" for s in ("intersection", "roundabout")}
    wait_for(lambda: all(log.exists() and "step    2000/3000" in log.read_text() for log in logs.values()),
             "both cells to train")
    subprocess.run(["scancel", "--batch", "--signal=USR1", f"{job}_0"], check=True)
    subprocess.run(["scancel", f"{job}_1"], check=True)
    wait_for(lambda: states(job) == {0: ("PENDING", 1), 1: ("CANCELLED", 0)}, "task 0 requeued, task 1 cancelled")
    # Slurm holds a requeued task for 2 min; start it now, a second after its end (slurmd refuses it in that second)
    time.sleep(2)
    subprocess.run(["scontrol", "update", f"JobId={job}_0", "StartTime=now"], check=True)
    again = submit(["--scenarios", "roundabout", *CELLS, *dirs], capsys, cluster)
    wait_for(lambda: completed(f"{job}_0", f"{again}_0"), "both cells to finish")
    for scenario, log in logs.items():
        text = log.read_text()
        stopped = re.search(r"interrupted at step (\d+): saving", text)
        assert stopped and int(stopped[1]) >= 2000, text
        assert f"training sac on the {scenario} from step {stopped[1]} to 3000" in text, text  # not from step 0
        assert text.count("UTC: start, 1 thread(s)") == 2 and "UTC: finished after" in text, text
        assert (tmp_path / "results" / "runs" / log.parent.name / "eval.json").exists()
    out = (tmp_path / "work" / f"slurm-{job}_0.out").read_text()
    assert f"requeueing task {job}_0" in out and out.count("--resume") == 1, out
    (tmp_path / "results" / "table3.md").unlink()
    slurm.main([*CELLS, *dirs, "--collect"])
    assert capsys.readouterr().out.count("| SAC (") == 2


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
    assert "#SBATCH --partition=gpu" in slurm.job_file(todo, Namespace(**{**vars(args), "partition": "gpu"}))
    assert [slurm.seconds(t) for t in ("90", "1:30", "2:00:00", "1-2", "1-00:00:30", "2h")] == [
        5400, 90, 7200, 93600, 86430, None]
