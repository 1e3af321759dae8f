"""The two road networks of the paper (Sec. 5.1) as SUMO files, and how SUMO is found and reads them.

    intersection.*.xml, roundabout.*.xml   the networks: plain XML, built by `python scenarios/build.py`
    sumo_home, scenario_files, check_network   for world.py: where SUMO is, the files, can SUMO read them
    follow                                 for world.py: the lanes of a route, read from the running SUMO
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent


def sumo_home() -> Path:
    try:
        import sumo  # the eclipse-sumo wheel
        return Path(sumo.SUMO_HOME)
    except ImportError:
        if os.environ.get("SUMO_HOME"):
            return Path(os.environ["SUMO_HOME"])
        raise SystemExit("SUMO is not installed: pip install -r requirements.txt (eclipse-sumo, libsumo)")


def scenario_files(scenario: str) -> tuple[Path, Path]:
    """The network and route files of a scenario (scenarios/), checked to exist."""
    files = tuple(HERE / f"{scenario}.{x}.xml" for x in ("net", "rou"))
    for f in files:
        if not f.is_file():
            raise SystemExit(f"missing {f}: rebuild the networks with `python scenarios/build.py`")
    return files


_checked: set[tuple] = set()  # network and route files SUMO has read in this process, as they were


def check_network(net: Path, rou: Path):
    """SUMO can read the scenario's files, or one line saying why not. Tried in a subprocess, once per process
    and version of the files: libsumo takes the process down on a broken network (an evaluation worker too)."""
    key = tuple((str(f), f.stat().st_mtime_ns) for f in (net, rou))
    if key in _checked:
        return
    check = subprocess.run([str(sumo_home() / "bin" / "sumo"), "-n", str(net), "-r", str(rou), "--end", "0"],
                           capture_output=True, text=True)
    if check.returncode != 0:
        error = next((line for line in (check.stderr + check.stdout).splitlines() if "rror" in line),
                     f"SUMO crashed reading it (exit code {check.returncode}), is it valid XML?")
        raise SystemExit(f"SUMO cannot load {net.name}: {error.strip()} Rebuild the networks with "
                         "`python scenarios/build.py`.")
    _checked.add(key)


def follow(lanes_api, edges, lane):
    """The lanes (internal ones included) a vehicle on `lane` takes along `edges`, or None. lanes_api: the running
    simulation's lane domain (libsumo.lane or traci.lane)."""
    lanes = [lane]
    for nxt in edges[1:]:
        links = [link for link in lanes_api.getLinks(lanes[-1]) if link[0].rsplit("_", 1)[0] == nxt]
        if not links:
            return None
        via = links[0][4]
        while via:  # an internal lane, possibly split at an internal junction
            lanes.append(via)
            inner = lanes_api.getLinks(via)
            via = inner[0][4] if inner and inner[0][4] and inner[0][4] not in lanes else ""
        lanes.append(links[0][0])
    return lanes
