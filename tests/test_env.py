"""The environment on the real simulator (libsumo): the ego's dynamics, collisions, the game in SUMO."""
import math
import tempfile

import numpy as np
import pytest

import world
from world import EnvConfig


@pytest.fixture(scope="module")
def empty_env():
    """The intersection with no humans: the ego alone, or with vehicles a test places itself."""
    env = world.DrivingEnv(EnvConfig(scenario="intersection", spawn_gap=math.inf, warmup=0.0))
    yield env
    env.close()


def test_ego_realises_the_commanded_acceleration(empty_env):
    env, dt = empty_env, empty_env.cfg.dt
    obs, info = env.reset(seed=0, options={"route": "S_N"})
    assert env.v == pytest.approx(8.0)  # the depart speed
    for a in [2.0, 2.0, 1.0, 0.0, -1.0, -3.0, -3.0, 0.5, 5.0, -9.0]:
        v, s = env.v, env.s
        obs, r, terminated, truncated, info = env.step(a)
        expected = min(max(a, -3.0), 2.0)  # commands beyond [-3, 2] are clipped
        assert env.v == pytest.approx(max(0.0, v + expected * dt), abs=1e-9)
        assert env.s - s == pytest.approx(env.v * dt, abs=1e-6)  # SUMO's Euler position update
        assert obs[6] == pytest.approx(env.v / 16.0, abs=1e-6)
        assert not terminated and not truncated


def test_full_throttle_into_crossing_traffic_is_a_detected_collision(empty_env):
    env, sim = empty_env, empty_env.sim
    env.reset(seed=0, options={"route": "S_N"})
    # a human crossing from the west, ignoring everyone, that stalls across the ego's lane
    # (x = 4.8 m) just before the ego (at 8 m/s + 2 m/s^2) gets there
    sim.vehicle.add("crosser", "W_E", typeID="human", depart="now", departLane="1", departSpeed="14")
    sim.vehicle.setSpeedMode("crosser", 0)
    done, steps = False, 0
    while not done:
        if "crosser" in sim.vehicle.getIDList():
            stalled = sim.vehicle.getPosition("crosser")[0] > 7.0  # front bumper [m]
            sim.vehicle.setSpeed("crosser", 0.0 if stalled else 14.0)
        obs, r, terminated, truncated, info = env.step(2.0)
        done, steps = terminated or truncated, steps + 1
    assert info["collision"] and not info["arrival"] and terminated
    assert r == -20.0 and info["cost"] == 1.0
    assert steps < 60  # it happened in the junction, not after a timeout
    sim.vehicle.remove("crosser")


def test_arrival_ends_the_episode_with_the_crossing_time(empty_env):
    env = empty_env
    env.reset(seed=0, options={"route": "S_N"})
    rewards, done = [], False
    while not done:
        obs, r, terminated, truncated, info = env.step(0.0)  # 8 m/s all the way
        rewards.append(r)
        done = terminated or truncated
    assert info["arrival"] and terminated and rewards[-1] == 20.0
    # S_N: the route's destination lies 20 m into the exit road, 93.6 m from the ego's start
    assert info["crossing_time"] == pytest.approx(93.6 / 8.0, abs=0.25)
    assert rewards[0] == pytest.approx((8.0 - 1.0) / 9.0 * 0.5)  # Eq. (31) at 8 m/s


def test_observation_sees_a_vehicle_ahead(empty_env):
    env, sim = empty_env, empty_env.sim
    env.reset(seed=0, options={"route": "S_N"})
    sim.vehicle.add("ahead", "S_N", typeID="human", depart="now", departLane="1", departPos="40", departSpeed="0")
    sim.vehicle.setSpeedMode("ahead", 0)
    sim.vehicle.setSpeed("ahead", 0.0)
    obs, *_ = env.step(0.0)
    obs, *_ = env.step(0.0)
    front = obs[7:].reshape(6, 2, 5)[0, 0]
    gap = 40.0 - env.s  # both front bumpers on the same straight lane [m]
    assert front[0] == 1.0 and front[1] == pytest.approx(gap / 60.0, abs=1e-3)
    assert front[3] == pytest.approx(0.5, abs=1e-3)  # dead ahead: the middle of (-30, 30]
    assert env.base_action() < 0.0  # the planner brakes for it
    sim.vehicle.remove("ahead")


def test_level_k_yield_is_enforced_in_sumo():
    """Busy traffic: every human the game tells to yield is held, and released when the game ends."""
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    try:
        env.reset(seed=3)
        seen = 0
        for _ in range(600):
            obs, r, terminated, truncated, info = env.step(env.base_action())
            if terminated or truncated:
                assert not env.decisions and not env.capped  # everyone handed back to SUMO
                env.reset()
                continue
            for h, k in env.decisions.items():
                seen += 1
                ignored = env.sim.vehicle.getParameter(h, "junctionModel.ignoreIDs")
                assert ignored == ("ego" if k == world.CROSS else "")
        assert seen > 0  # games were played
    finally:
        env.close()


def test_a_human_stuck_inside_the_junction_is_removed_and_the_ego_never(empty_env):
    """Humans who stop inside a junction for jam_time leave the simulation (a gridlock of humans never
    resolves); the ego, standing inside the junction longer still, stays."""
    env, sim = empty_env, empty_env.sim
    env.reset(seed=0, options={"route": "S_N"})
    sim.vehicle.add("stuck", "N_S", typeID="human", depart="now", departSpeed="max")
    stopped = {}  # vehicle -> time [s] it was stopped inside the junction
    for _ in range(round(60.0 / env.cfg.dt)):
        ids = sim.vehicle.getIDList()
        for v in ("stuck", world.EGO):
            if v in ids and v not in stopped and sim.vehicle.getLaneID(v).startswith(":"):
                stopped[v] = sim.simulation.getTime()
                sim.vehicle.setSpeed(v, 0.0)  # held here, as by a gridlock
        if "stuck" in stopped and "stuck" not in ids:
            break
        obs, r, terminated, truncated, info = env.step(-3.0 if world.EGO in stopped or env.v > 3.0 else 0.0)
        assert not (terminated or truncated), info
    assert set(stopped) == {"stuck", world.EGO}
    assert "stuck" not in sim.vehicle.getIDList()  # removed ...
    assert sim.simulation.getTime() - stopped["stuck"] == pytest.approx(env.cfg.jam_time, abs=1.5)  # ... on time
    for _ in range(round(60.0 / env.cfg.dt)):  # the ego stands inside for jam_time + 2 s
        if sim.vehicle.getWaitingTime(world.EGO) >= env.cfg.jam_time + 2.0:
            break
        obs, r, terminated, truncated, info = env.step(-3.0)
    assert sim.vehicle.getWaitingTime(world.EGO) >= env.cfg.jam_time + 2.0
    assert sim.vehicle.getLaneID(world.EGO).startswith(":") and env.jam_removals >= 1


def test_unknown_scenario_is_refused():
    with pytest.raises(ValueError, match="unknown scenario"):
        world.DrivingEnv(EnvConfig(scenario="highway"))


def test_a_broken_network_is_one_line_not_a_traceback(tmp_path):
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    env.net_file = tmp_path / "broken.net.xml"
    env.net_file.write_text("<net><edge id=")
    with pytest.raises(SystemExit, match="SUMO cannot load broken.net.xml: .*scenarios/build.py"):
        env.reset(seed=0)
    ok = world.DrivingEnv(EnvConfig(scenario="intersection", spawn_gap=math.inf, warmup=0.0))
    ok.reset(seed=0)  # the next simulation starts normally
    ok.close()


@pytest.mark.parametrize("action", [np.nan, None, [1.0, 2.0], [], np.inf, "fast"])
def test_a_bad_action_is_refused(empty_env, action):
    empty_env.reset(seed=0, options={"route": "S_N"})
    with pytest.raises(ValueError, match="one finite acceleration"):
        empty_env.step(action)


def test_a_yielding_human_stops_before_the_conflict_point(monkeypatch):
    """Every human in a game is told to YIELD; the ego stops before the roundabout's entry, ~14 m from its
    merge. Humans on the ring have the right of way and never stop for an entry on their own (without the
    speed caps none stops here): those that stop were held.
    A human told to yield when it can no longer stop within its own braking (decel) is left out."""
    monkeypatch.setattr(world, "level_k_decisions", lambda t_h, *args: np.full(len(t_h), world.YIELD))
    env = world.DrivingEnv(EnvConfig(scenario="roundabout"))
    margin, could_stop, stopped_at = env.cfg.stop_margin, {}, {}
    try:
        env.reset(seed=2, options={"route": "S_N"})
        for _ in range(200):
            obs, r, terminated, truncated, info = env.step(-3.0 if env.s > 50.0 or env.v == 0 else 0.0)
            assert not (terminated or truncated), info
            foes = {}  # human -> (ego's, human's distance [m]) to the conflict point the game plays for
            for h, d_e, d_h, *_ in env.sim.vehicle.getJunctionFoes(world.EGO, 60.0):
                if env.decisions.get(h) == world.YIELD and d_e > 0 and d_h > 0 and d_e < foes.get(h, (np.inf,))[0]:
                    foes[h] = (d_e, d_h)
            for h, (_, d) in foes.items():
                v = env.sim.vehicle.getSpeed(h)
                could_stop.setdefault(h, v * v / (2 * max(d - margin, 1e-9)) <= env.humans[h][5])
                if v < 0.1 and could_stop[h] and d < 20.0:  # near its conflict point: not queued far away
                    stopped_at[h] = min(d, stopped_at.get(h, np.inf))
        assert len(stopped_at) >= 2  # held by the game
        assert min(stopped_at.values()) > margin  # before the conflict point and its junction
    finally:
        env.close()


def test_two_drivers_meet_the_same_test_cases():
    """Case c of a round is the same traffic, departures and ego route for every model (Table 3)."""
    import experiment
    import tarl
    env = world.DrivingEnv(EnvConfig(scenario="roundabout"))
    try:
        planner_only = experiment.play_round(env, [tarl.Driver("planner")], cases=4, seed=0, round_=0)[0]
        full_throttle = tarl.Driver("none", type("Throttle", (), {"act": lambda self, obs, det: np.array([2.0])})())
        reckless = experiment.play_round(env, [full_throttle], cases=4, seed=0, round_=0)[0]
        with tempfile.TemporaryDirectory() as folder:  # a case played alone, after others: the same episode
            cases = env.record_cases(experiment.test_seed(0, 0), 4, folder)
            alone = experiment.rollout(env, tarl.Driver("planner"), {"case": cases[2]})
    finally:
        env.close()
    assert [alone[k] for k in ("start", "outcome", "steps")] == [planner_only[2][k] for k in ("start", "outcome", "steps")]
    assert [ep["start"] for ep in planner_only] == [ep["start"] for ep in reckless]
    assert len({ep["start"] for ep in planner_only}) == 4  # four different cases
    assert [ep["steps"] for ep in planner_only] != [ep["steps"] for ep in reckless]  # the drivers differ


def test_a_case_starts_the_same_whatever_ran_before():
    """A test case is its saved state alone: what the simulation did before the load must not change how
    the case begins. SUMO 1.28 carries something of the run before a loadState over: loaded after an
    episode that had just played the case's first step, a case let a waiting human enter a step late."""
    import experiment
    env = world.DrivingEnv(EnvConfig(scenario="roundabout"))

    def start(case):  # every vehicle's position after the reset, and the fingerprint
        env.reset(options={"case": case})
        return sorted((v, *np.round(env.sim.vehicle.getPosition(v), 3)) for v in env.sim.vehicle.getIDList()), env.fingerprint()

    try:
        with tempfile.TemporaryDirectory() as folder:
            cases = env.record_cases(experiment.test_seed(0, 1), 4, folder)
            # after the recording; after an episode that ended at the case's first step; after another case
            starts = [start(cases[3]), start(cases[3]), start(cases[0]), start(cases[3])]
    finally:
        env.close()
    assert starts[2] != starts[0]
    assert starts[0] == starts[1] == starts[3]


def test_every_human_keeps_its_lane_after_a_case_loads():
    """The lane rule (lane-change mode 0: lanes are chosen at departure) holds for every human of a loaded test case,
    those that were still waiting to depart at the snapshot included: a saved state forgets the mode, and SUMO 1.28
    lists those waiting only after a step. Checked after every step, with each human's lane on each edge."""
    import experiment
    env = world.DrivingEnv(EnvConfig(scenario="roundabout"))
    late, lanes = set(), {}
    try:
        with tempfile.TemporaryDirectory() as folder:
            for case in env.record_cases(experiment.test_seed(0, 0), 6, folder):
                env.reset(options={"case": case})
                present = set(env.sim.vehicle.getIDList())
                done = False
                while not done:
                    _, _, terminated, truncated, _ = env.step(env.base_action())
                    done = terminated or truncated
                    for h in env.sim.vehicle.getIDList():
                        if h == world.EGO:
                            continue
                        assert env.sim.vehicle.getLaneChangeMode(h) == 0, h
                        late |= {h} & (case["humans"].keys() - present)  # waiting at the snapshot
                        edge, lane = env.sim.vehicle.getRoadID(h), env.sim.vehicle.getLaneIndex(h)
                        assert lanes.setdefault((case["seed"][1], h, edge), lane) == lane, f"{h} changed lanes on {edge}"
    finally:
        env.close()
    assert late  # the vehicles the rule used to miss did enter


# ---- EnvConfig's traffic shifts (spawn_gap, svo_range, human_level): the defaults are the paper's ----

def _play_cases(cfg, seed=3, n=3):
    """The fingerprints of n recorded cases, each played at 0.5 m/s^2 to its end, and the humans recorded."""
    env, prints = world.DrivingEnv(cfg), []
    try:
        with tempfile.TemporaryDirectory() as folder:
            cases = env.record_cases(seed, n, folder)
            for case in cases:
                env.reset(options={"case": case})
                prints.append(env.fingerprint())
                done = False
                while not done:
                    obs, r, terminated, truncated, info = env.step(0.5)
                    prints.append(env.fingerprint())
                    done = terminated or truncated
    finally:
        env.close()
    return prints, [case["humans"] for case in cases]


def test_the_default_traffic_is_table_1_and_level_2_spelled_out():
    default, humans = _play_cases(EnvConfig(scenario="roundabout"))
    explicit, humans_explicit = _play_cases(EnvConfig(scenario="roundabout", svo_range=(0.0, 0.5), human_level=2))
    assert len(default) > 3 and default == explicit
    assert all(h.keys() == g.keys() and all(np.array_equal(h[k], g[k]) for k in h) for h, g in zip(humans, humans_explicit))


def test_an_svo_range_changes_only_the_svo_of_the_same_humans():
    cfg = EnvConfig(scenario="roundabout", warmup=30.0)
    env = world.DrivingEnv(cfg)
    try:
        with tempfile.TemporaryDirectory() as folder:
            paper = env.record_cases(5, 2, folder)
            env = world.DrivingEnv(EnvConfig(scenario="roundabout", warmup=30.0, svo_range=(0.9, 0.9)))
            selfless = env.record_cases(5, 2, folder)
    finally:
        env.close()
    for a, b in zip(paper, selfless):
        assert a["humans"].keys() == b["humans"].keys() and a["n_humans"] == b["n_humans"] > 5
        for h in a["humans"]:  # one draw per parameter in the same order: the other parameters agree
            assert 0.0 <= a["humans"][h][4] <= 0.5 and b["humans"][h][4] == 0.9
            np.testing.assert_array_equal(np.delete(a["humans"][h], 4), np.delete(b["humans"][h], 4))


def test_the_humans_play_the_configured_level(monkeypatch):
    levels, game = [], world.level_k_decisions
    monkeypatch.setattr(world, "level_k_decisions", lambda *args: levels.append(args[-1]) or game(*args))
    env = world.DrivingEnv(EnvConfig(scenario="roundabout", human_level=0))
    try:
        env.reset(seed=0)  # a human meets the ego at once
        for _ in range(150):
            if env.step(0.0)[2:4] != (False, False) or levels:
                break
    finally:
        env.close()
    assert levels and set(levels) == {0}


@pytest.mark.parametrize("bad, message", [
    (dict(human_level=-1), "human_level"), (dict(human_level=1.5), "human_level"), (dict(human_level=True), "human_level"),
    (dict(svo_range=(0.6, 0.2)), "svo_range"), (dict(svo_range=(-0.1, 0.5)), "svo_range"),
    (dict(svo_range=(0.5, 1.2)), "svo_range"), (dict(svo_range=0.3), "svo_range"),
    (dict(spawn_gap=0.0), "spawn_gap"), (dict(spawn_gap=-1.0), "spawn_gap"), (dict(spawn_gap=math.nan), "spawn_gap")])
def test_a_bad_traffic_setting_is_refused_before_sumo_starts(monkeypatch, bad, message):
    monkeypatch.setattr(world.DrivingEnv, "_start", lambda *args, **kw: pytest.fail("SUMO was started"))
    with pytest.raises(ValueError, match=message):
        world.DrivingEnv(EnvConfig(scenario="roundabout", **bad)).reset(seed=0)
