"""The proof's goals table (README's, written by the calibration_goals stage from the proof metrics)."""
from rdnet.calib.proof import goals_table


def test_goals_table_counts_every_block_and_the_total():
    def summary(n, named, nulls):
        return {"concealed_cases": n, "named_right_first": named, "ranked_first": n, "params_within_25pct": named - 1,
                "heldout_halved": 2, "heldout_excess_over_noise_floor_halved": 3, "null_cases": 3,
                "null_named_nothing": nulls}
    md = goals_table({"summary": summary(4, 3, 3), "cases": {}, "circuit": {"summary": summary(5, 2, 2), "cases": {}},
                      "reliability": {"ece": 0.1}})
    lines = md.splitlines()
    assert lines[2] == "| rdnet | 4 | 3 | 4 | 2 | 2 | 3 | 3 of 3 |"
    assert lines[3] == "| circuit | 5 | 2 | 5 | 1 | 2 | 3 | 2 of 3 |"
    assert lines[4] == "| **all** | **9** | **5** | **9** | **3** | **4** | **6** | **5 of 6** |"
    assert len(lines) == 5
