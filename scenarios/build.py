"""Rebuild the two SUMO road networks of tarl from their plain XML.

    python scenarios/build.py

The networks are written by hand as plain XML, one set per scenario:
  <name>.nod.xml  nodes (junction positions and types)
  <name>.edg.xml  edges (lane counts, speed limits, ring shapes)
  <name>.con.xml  lane-to-lane connections (which lane may go where)
  <name>.rou.xml  one <route> per movement, id "<from>_<to>" (not built here)
Edit those, then run this script: it calls netconvert and overwrites
<name>.net.xml, which is what SUMO loads. Check the result with
`sumo-gui -n scenarios/<name>.net.xml`.

Options: --no-turnarounds (no U-turn connections), --offset.disable-normalization
(keeps the centre at (0, 0)), --default.lanewidth 3.2 (paper, Table 1: 3.2 m).
"""
import os
import shutil
import subprocess

HERE = os.path.dirname(os.path.abspath(__file__))
SCENARIOS = ("intersection", "roundabout")
LANE_WIDTH = 3.2  # [m], paper Table 1


def netconvert_binary() -> str:
    """netconvert from the eclipse-sumo wheel if installed, else from PATH."""
    try:
        import sumo
        path = os.path.join(sumo.SUMO_HOME, "bin", "netconvert")
        if os.path.exists(path):
            return path
    except ImportError:
        pass
    path = shutil.which("netconvert")
    if path is None:
        raise RuntimeError("netconvert not found: pip install eclipse-sumo")
    return path


def build(name: str) -> str:
    """Build scenarios/<name>.net.xml from the plain XML files; return its path."""
    # run inside scenarios/ so the header of the .net.xml holds relative paths
    subprocess.run([
        netconvert_binary(),
        "--node-files", name + ".nod.xml",
        "--edge-files", name + ".edg.xml",
        "--connection-files", name + ".con.xml",
        "--no-turnarounds",
        "--offset.disable-normalization",
        "--default.lanewidth", str(LANE_WIDTH),
        "--output-file", name + ".net.xml",
    ], check=True, cwd=HERE)
    return os.path.join(HERE, name + ".net.xml")


if __name__ == "__main__":
    for scenario in SCENARIOS:
        print("built", build(scenario))
