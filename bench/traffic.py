"""Does the traffic keep flowing? Throughput, waits and queues of the humans alone (no ego).

    python bench/traffic.py --scenario roundabout --seconds 1000 --seeds 1 2 3

Runs DrivingEnv's own traffic (Table 1 humans, network-wide spawn gaps, SUMO settings) for
the given simulated time after the warm-up and prints, per seed: departures asked for,
inserted, dropped (not insertable within 30 s), arrived per second, mean and max waiting
time of the arrived humans, teleports, collisions among humans, the most vehicles at once,
and the longest a vehicle has stood within 12 m of a spawn point.
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import world  # noqa: E402


def measure(scenario: str, seconds: float, seed: int) -> dict:
    env = world.DrivingEnv(world.EnvConfig(scenario=scenario))
    env.rng = np.random.default_rng(seed)
    env._start(seed)  # SUMO with the environment's settings, warmed up
    sim, dt = env.sim, env.cfg.dt
    spawn_lanes = {t["first"] for t in env.tasks}
    asked0 = env.n_humans
    departed = arrived = teleports = collisions = most = 0
    waited, done_waits = {}, []  # [s] standing time per human, and that of the arrived
    standing, longest_at_spawn = {}, 0.0
    for _ in range(round(seconds / dt)):
        env._spawn_humans()
        sim.simulationStep()
        now = sim.simulation.getTime()
        departed += sim.simulation.getDepartedNumber()
        for h in sim.simulation.getArrivedIDList():
            arrived += 1
            done_waits.append(waited.pop(h, 0.0))
        teleports += sim.simulation.getStartingTeleportNumber()
        collisions += sim.simulation.getCollidingVehiclesNumber()
        ids = sim.vehicle.getIDList()
        most = max(most, len(ids))
        for v in ids:
            if sim.vehicle.getSpeed(v) < 0.1:
                waited[v] = waited.get(v, 0.0) + dt
                if sim.vehicle.getLaneID(v) in spawn_lanes and sim.vehicle.getLanePosition(v) < 12.0 + env.cfg.length:
                    standing.setdefault(v, now)
                    longest_at_spawn = max(longest_at_spawn, now - standing[v])
                    continue
            standing.pop(v, None)
    asked = env.n_humans - asked0
    pending = len(sim.simulation.getPendingVehicles())
    env.close()
    return {"scenario": scenario, "seed": seed, "seconds": seconds, "departures_asked": asked,
            "inserted": departed, "dropped": asked - departed - pending, "arrived_per_s": round(arrived / seconds, 3),
            "demand_per_s": round(1.0 / env.spawn_gap, 3),
            "wait_mean_s": round(float(np.mean(done_waits)), 2), "wait_max_s": round(float(np.max(done_waits)), 1),
            "teleports": teleports, "collisions": collisions, "most_vehicles": most,
            "longest_standing_at_spawn_s": round(longest_at_spawn, 1)}


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", choices=sorted(world.SCENARIOS), default="intersection")
    p.add_argument("--seconds", type=float, default=1000.0)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    a = p.parse_args()
    for s in a.seeds:
        print(json.dumps(measure(a.scenario, a.seconds, s)))
