"""The session length told to participants before they start."""

from __future__ import annotations

from study_app.duration import describe_duration, estimate_minutes


def test_paper_design_brackets_the_reported_duration():
    """CGVQM+D: 80 stimuli x 3 repetitions of 3 s loops took participants 60-90 minutes."""
    low, high = estimate_minutes(240, 3.0, 0.5)
    assert low <= 60 and high >= 85 and high <= 100


def test_scales_with_trials_and_loop_length():
    assert estimate_minutes(120, 3.0, 0.5)[1] < estimate_minutes(240, 3.0, 0.5)[1]
    assert estimate_minutes(240, 6.0, 0.5)[0] > estimate_minutes(240, 3.0, 0.5)[0]
    assert estimate_minutes(0, 3.0, 0.5) == (0, 0)


def test_wording():
    assert describe_duration(3, 1.0, 0.5) == "about 1 minute (3 trials), plus the breaks you take"
    assert describe_duration(240, 3.0, 0.5).startswith("about 50-90 minutes (240 trials)")


def _manifest(protocol: dict):
    from stimuli_manifests import parse_manifest

    refs = [{"path": f"r{i}.mkv", "scene": f"s{i}", "width": 8, "height": 8, "fps": 30,
             "frames": 30} for i in range(2)]
    conds = [{"reference": f"SRC{i + 1:02d}", "method": "m", "level": lv,
              "path": f"r{i}_{lv}.mkv"} for i in range(2) for lv in (1, 2, 3)]
    return parse_manifest({"study_id": "d", "root": "v", "protocol": protocol,
                           "references": refs, "conditions": conds})


def test_a_whole_session_counts_every_repetition_or_every_block():
    """6 test videos + 2 hidden references = 8 stimuli; x3 repetitions, or 8 in the first
    adaptive block and 5 in each of the 3 later ones."""
    from study_app.duration import later_block_trials, session_trials

    assert session_trials(_manifest({"repetitions": 3})) == 24
    adaptive = _manifest({"allocation": "adaptive",
                          "adaptive": {"blocks": 4, "block_trials": 5}})
    assert session_trials(adaptive) == 8 + 3 * 5
    assert later_block_trials(adaptive, 3) == 5 and later_block_trials(adaptive, 4) == 0
