"""Leave one video out (`evaluation.videos`): a video's answers are its rows alone, and the figure over the
videos is their mean, each share averaged and each count summed."""

from __future__ import annotations

import pytest

from evaluation.openset import Answers
from evaluation.videos import mean_of, of_videos


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
