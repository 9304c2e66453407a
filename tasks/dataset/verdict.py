"""Whether a dataset can be trained on, and if not why, in one line.

A MAAIP run learns its interaction priors D^I from both fighters' interaction transitions and
starts its episodes from their frames (Younes et al. 2023, §4), all from the train split: a
dataset without interaction clips in its train split teaches nothing, however many transitions
it holds (footage of one person walking made 127). The verdict names the first link missing in
the chain adversary lifted -> opponent lifted -> both lifted together -> in the train split, so
that the fix it points at is the real one.

It is read from the clips a dataset already has (`dataset_clips`), not stored: datasets
assembled before it existed get one too, and it cannot disagree with their clips.
"""

from __future__ import annotations

from collections.abc import Iterable

from models.humanoid.motion import RATE

_CLIPS = "dataset.min_clip_s"
_LIFT = "`ringside metrics --stage lift` (frames_rejected_*) says what the lift dropped"


def unusable_reason(clips: Iterable[tuple[str, str | None, str, int]]) -> str | None:
    """Why a dataset with these clips cannot be trained on, in one line; None when it can.

    Args:
        clips: one (kind, role, split, steps) per clip of every member: kind "single" (role
            "adversary", "opponent" or "extra") or "interaction" (role None), split "train"
            or "validation", steps its length on the 30 Hz grid.
    """
    seconds: dict[str, float] = {}
    interaction = {"train": 0, "validation": 0}
    for kind, role, split, steps in clips:
        if kind == "interaction":
            interaction[split] += 1
        else:
            seconds[role] = seconds.get(role, 0.0) + steps / RATE
    adversary, opponent = seconds.get("adversary", 0.0), seconds.get("opponent", 0.0)
    if interaction["train"]:
        return None
    if not adversary and not opponent:
        return f"no fighter was lifted for {_CLIPS} without a break; {_LIFT}"
    if not adversary:
        return (
            f"no adversary frames: the adversary was never lifted for {_CLIPS} without a break, "
            f"only the opponent ({opponent:.1f} s); {_LIFT}, and `ringside pick` sets the "
            "adversary if the wrong person was taken"
        )
    if not opponent:
        return (
            f"one fighter only: no opponent was lifted for {_CLIPS} without a break, only the "
            f"adversary ({adversary:.1f} s); training needs footage of two people fighting (the "
            "pose stage's notes say whether a second person was found)"
        )
    if not interaction["validation"]:
        return (
            f"no interaction: the two fighters were never lifted together for {_CLIPS} without "
            f"a break ({adversary:.1f} s of the adversary, {opponent:.1f} s of the opponent, "
            f"apart); {_LIFT} and `--stage dataset` (steps_rejected) what the dataset dropped"
        )
    return (
        f"empty train split: its {interaction['validation']} interaction clips are all in the "
        "validation split (dataset.validation_fraction); add footage of both fighters"
    )
