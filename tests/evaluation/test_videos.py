"""Leave one video out (`evaluation.videos`): a video's answers are its rows alone, and the figure over the
videos is their mean, each share averaged and each count summed."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.openset import Answers
from evaluation.videos import mean_of, of_videos, weights_by_video


def answers() -> Answers:
    """Four rows: scenes 0, 1, 1, 2, one score kind."""
    return Answers(
        obj=[1, 2, 3, 4],
        registered=[True, True, False, True],
        run=[0, 0, 1, 0],
        frame=[5, 6, 6, 7],
        scene=[0, 1, 1, 2],
        objects={"descriptor": [[1], [2], [2], [4]]},
        distances={"descriptor": [[0.1], [0.2], [0.3], [0.4]]},
        settings={"descriptor": {"level": 3}},
        data="real",
        unexplained={"descriptor": [0.0, 0.5, None, 1.0]},
    )


def test_a_videos_answers_are_its_rows_alone():
    one = of_videos(answers(), [1])
    assert one.obj == [2, 3] and one.scene == [1, 1] and one.registered == [True, False]
    assert one.distances == {"descriptor": [[0.2], [0.3]]}
    assert one.unexplained == {"descriptor": [0.5, None]}
    assert one.colours == {} and one.settings == {"descriptor": {"level": 3}} and one.data == "real"
    two = of_videos(answers(), [0, 2])
    assert two.obj == [1, 4] and two.frame == [5, 7]
    assert of_videos(answers(), [9]).obj == []


def test_answers_without_their_scenes_are_refused():
    a = answers()
    a.scene = []
    with pytest.raises(ValueError, match="scenes"):
        of_videos(a, [0])


def test_the_figure_over_videos_is_their_mean_and_their_counts_summed():
    block: dict[int, dict] = {
        0: {
            "per_unregistered_object": {"1": {"n": 20, "rejected_unknown": 0.5}},
            "by_registered": {
                "9": {"runs": 4, "n_unknown": 60, "rejected_unknown": 0.6, "rejected_wrong": None}
            },
        },
        1: {
            "per_unregistered_object": {"2": {"n": 40, "rejected_unknown": 0.0}},
            "by_registered": {
                "9": {"runs": 4, "n_unknown": 120, "rejected_unknown": 0.2, "rejected_wrong": 1.0}
            },
        },
    }
    mean = mean_of(block)
    assert mean["videos"] == [0, 1]
    by = mean["by_registered"]["9"]
    assert by["rejected_unknown"] == pytest.approx(0.4)  # the mean of the videos, not weighed by patches
    assert by["n_unknown"] == 180 and by["runs"] == 8
    assert by["rejected_wrong"] == 1.0  # the one video that has wrong answers
    assert by["recognised"] is None  # no video says
    assert mean["per_unregistered_object"] == {
        "1": {
            "n": 20,
            **dict.fromkeys(("recognised", "rejected_registered", "rejected_right", "rejected_wrong")),
        }
        | {"rejected_unknown": 0.5},
        "2": {
            "n": 40,
            **dict.fromkeys(("recognised", "rejected_registered", "rejected_right", "rejected_wrong")),
        }
        | {"rejected_unknown": 0.0},
    }


def test_the_statistic_is_chosen_on_the_other_videos_and_measured_on_the_one_left_out():
    """Three videos; object 2 left out in run 1. In videos 0 and 1 the unregistered object's best answer is
    near but its depth explains none of it: only a fit term separates it there. Video 2 is chosen on 0 and 1,
    so it gets a fit term and its unknown is rejected; the statistic held fixed without one rejects none."""
    rows = []  # scene, run, obj, ids, distances, unexplained
    for scene in (0, 1, 2):
        for k in range(6):
            near = 0.1 + 0.01 * k
            rows += [
                (scene, 0, 1, [1, 1, 2], [near, near + 0.01, 0.5], 0.05),
                (scene, 0, 2, [2, 2, 1], [near, near + 0.02, 0.5], 0.05),
                (scene, 1, 1, [1, 1, -1], [near, near + 0.01, np.nan], 0.05),
                (scene, 1, 2, [1, 1, -1], [near, near + 0.01, np.nan], 0.9),  # unregistered: looks known
            ]
    a = Answers(
        obj=[r[2] for r in rows],
        registered=[r[1] == 0 or r[2] != 2 for r in rows],
        run=[r[1] for r in rows],
        frame=list(range(len(rows))),
        scene=[r[0] for r in rows],
        objects={"descriptor": [r[3] for r in rows]},
        distances={"descriptor": [r[4] for r in rows]},
        settings={"descriptor": {"level": 3}},
        data="real",
        unexplained={"descriptor": [r[5] for r in rows]},
    )
    got = weights_by_video(a, "descriptor", ("registered", 0.1), [[1, 2], [1]], 1, (0.5, 0.0))
    for video in ("0", "1", "2"):
        chosen, fixed = got["videos"][video]["chosen"], got["videos"][video]["shipped"]
        assert chosen["fit"] > 0 and chosen["rejected_unknown"] == 1.0, chosen
        assert fixed["fit"] == 0.0 and fixed["rejected_unknown"] < 1.0, fixed
    assert got["mean"]["chosen"]["rejected_unknown"] == 1.0
