"""The motion tracker: fighters following reference clips in the arena (DeepMimic's imitation,
DReCon's residual actions). The clip library (`clips`), the pure reward and errors (`reward`),
the tracking task and where its next frame comes from (`task`), the gate that plays every clip
from its first frame (`gate`) and the settings (`config`). MAAIP's trainer trains it
(`TrainerConfig.objective` 'track'); nothing here imports MAAIP."""
