"""The speed benchmark runs end to end (a smoke test: no timing is asserted, the machine is shared)."""
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))
import speed  # noqa: E402

KEYS = ("sac_updates_per_s", "sac_plain_updates_per_s", "sac_ratio", "timing_updates_per_s",
        "env_steps_per_s", "sumo_raw_steps_per_s", "planner_calls_per_s", "train_steps_per_s", "train_ppo_lag_steps_per_s",
        "train_cpo_steps_per_s", "cases_record_s",
        "cases_load_ms")


def test_speed_quick_prints_every_number_the_issue_asks_for(capsys):
    speed.main(["--quick", "--json"])
    r = json.loads(capsys.readouterr().out)
    for key in KEYS:
        assert key in r, key
    for sc in ("intersection", "roundabout"):
        assert r["env_steps_per_s"][sc] > 0 and r["sumo_raw_steps_per_s"][sc] > 0
        assert r["env"][sc]["vehicles_full"] > 0
    assert r["sac_updates_per_s"] > 0 and r["planner_calls_per_s"] > 0 and r["train_steps_per_s"] > 0
    assert r["train_ppo_lag_steps_per_s"] > 0 and r["train_cpo_steps_per_s"] > 0
    assert r["planner_candidates"] > 1
    assert 0.3 < r["sac_gflop_per_update"] < 2.0  # Table 2's sizes: about 0.64 GFLOP per update
