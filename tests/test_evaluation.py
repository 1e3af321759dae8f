"""The evaluation never hangs: a dead worker, a network SUMO cannot parse and SIGTERM each end the run in
one line, within a bound these tests enforce by killing the run. Real processes, the real simulator."""
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parents[1]
BOUND = 60.0  # [s] the longest a run may take to end; past it the test kills it and fails


def run(argv, cwd=HERE, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "tarl.py", *argv], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kw)


def finish(proc: subprocess.Popen, bound: float = BOUND) -> tuple[int, str, str]:
    """The run's exit code, stdout and stderr; killed (with its children) and failed if it takes longer than bound."""
    try:
        out, err = proc.communicate(timeout=bound)
    except subprocess.TimeoutExpired:
        for pid in [*children(proc.pid), proc.pid]:
            os.kill(pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"the run did not end within {bound} s")
    return proc.returncode, out, err


def children(pid: int) -> list[int]:
    """The processes whose parent is pid (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def workers(pid: int) -> list[int]:
    """The evaluation workers of run pid: its children started by multiprocessing's spawn."""
    def cmdline(p):
        try:
            return Path(f"/proc/{p}/cmdline").read_bytes().decode(errors="replace")
        except OSError:
            return ""
    return [p for p in children(pid) if "spawn_main" in cmdline(p)]


def wait_for(condition, bound: float = BOUND):
    t0 = time.time()
    while not condition():
        if time.time() - t0 > bound:
            pytest.fail(f"waited {bound} s")
        time.sleep(0.1)


EVAL = ["--scenario", "intersection", "--algo", "lattice-idm", "--eval-rounds", "3", "--eval-cases", "3"]


def test_a_worker_killed_mid_evaluation_ends_the_run_in_one_line_and_the_finished_rounds_stay(tmp_path):
    proc = run([*EVAL, "--workers", "1", "--out", str(tmp_path)])
    kept = tmp_path / "eval-rounds" / "round0.json"
    wait_for(lambda: kept.exists() or proc.poll() is not None)
    assert proc.poll() is None, "the run ended before a worker could be killed"
    (worker,) = workers(proc.pid)  # now playing round 2
    os.kill(worker, signal.SIGKILL)
    t0 = time.time()
    code, out, err = finish(proc, bound=20.0)
    assert code == 1 and time.time() - t0 < 10.0
    assert err.strip().splitlines() == ["evaluation round 2 failed: its worker process died (killed by SIGKILL); the "
                                        "finished rounds are kept, run the same command again to play the others"]
    assert kept.exists() and not workers(proc.pid)


def test_sigterm_during_evaluation_ends_the_run_and_its_workers_within_seconds(tmp_path):
    proc = run([*EVAL, "--workers", "2", "--out", str(tmp_path)])
    kept = tmp_path / "eval-rounds"
    wait_for(lambda: any(kept.glob("round*.json")) or proc.poll() is not None)
    assert proc.poll() is None
    spawned = workers(proc.pid)
    proc.send_signal(signal.SIGTERM)
    t0 = time.time()
    code, out, err = finish(proc, bound=20.0)
    assert code == 1 and time.time() - t0 < 5.0
    assert err.strip().splitlines() == [f"kept the finished rounds in {kept}; run the same command again to play the others"]
    assert any(kept.glob("round*.json"))
    assert not [p for p in spawned if Path(f"/proc/{p}").exists() and "Z" not in Path(f"/proc/{p}/stat").read_text()
                .rsplit(")", 1)[1].split()[0]]  # no worker left alive


def test_a_network_sumo_cannot_parse_is_one_line_with_workers(tmp_path):
    """A copy of the project whose roundabout network is cut short: the run fails at once, before any worker."""
    for f in HERE.glob("*.py"):
        shutil.copy(f, tmp_path / f.name)
    shutil.copytree(HERE / "scenarios", tmp_path / "scenarios")
    shutil.copytree(HERE / "beyond", tmp_path / "beyond")
    net = tmp_path / "scenarios" / "roundabout.net.xml"
    net.write_text(net.read_text()[:5000])
    proc = run(["--scenario", "roundabout", "--algo", "lattice-idm", "--eval-rounds", "1", "--eval-cases", "1",
                "--out", str(tmp_path / "out")], cwd=tmp_path)
    code, out, err = finish(proc, bound=40.0)
    assert code == 1
    (line,) = err.strip().splitlines()
    assert line.startswith("SUMO cannot load roundabout.net.xml: ") and "scenarios/build.py" in line
