"""The train stage's config: the trainer's settings (`TrainerConfig`, kept beside the trainer in
`models.maaip.config`, since the trainer imports nothing of the stages) and the stage's own: how
long a run lasts, when it checkpoints and which networks it starts from."""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.maaip.config import TrainerConfig
from models.settings import setting


@dataclass(frozen=True)
class TrainConfig(TrainerConfig):
    """The `[train]` settings: the trainer's (`TrainerConfig`) and the run's length,
    checkpoints and warm start (`tasks.train.run`, `tasks.train.store`)."""

    iterations: int = setting(1000, "Training iterations (collect, update D, update pi and V).")
    minutes: float = setting(
        0.0,
        "Wall-clock budget of the run in minutes: it ends at the first checkpoint after it, "
        "with the iterations done by then (resuming a killed run counts anew); 0 is none.",
    )
    checkpoint_every: int = setting(
        100,
        "Iterations between checkpoints (each holds the replay buffers: about 590 MB with the "
        "defaults); a killed run resumes from the newest and recomputes the iterations since.",
    )
    warm_start: bool = setting(
        True,
        "A new run starts from the networks (policy, value, discriminators) of the newest "
        "finished run on an earlier dataset of the same adversary with the same humanoids and "
        "network sizes, e.g. after a video was added to the footage, instead of from nothing; "
        "false always starts from a fresh initialisation.",
    )

    warm_from: str = setting(
        "",
        "A finished run (its key, or a prefix of it) whose networks a new run starts from, in "
        "place of `warm_start`'s choice: e.g. a tracker of the footage trained on further on "
        "matched streams (`train.track.matched_streams`). Its networks must have this run's "
        "shapes. Empty: `warm_start` chooses.",
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.iterations < 1:
            raise ValueError(f"train.iterations must be at least 1, got {self.iterations}")
        if not (math.isfinite(self.minutes) and self.minutes >= 0):
            raise ValueError(f"train.minutes must be >= 0, got {self.minutes}")
        if self.checkpoint_every < 1:
            raise ValueError(
                f"train.checkpoint_every must be at least 1, got {self.checkpoint_every}"
            )
