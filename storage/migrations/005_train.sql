-- train: one row per metric per training iteration (returns per reward term, discriminator
-- accuracies and gradient penalty, episode length, falls, damage, steps per second, time split).
-- video_id holds the dataset key the run learns from; key is the run's key.
CREATE TABLE train_iterations (
    key        VARCHAR NOT NULL,
    video_id   VARCHAR NOT NULL,
    iteration  INTEGER NOT NULL,
    name       VARCHAR NOT NULL,
    value      DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, iteration, name)
);

-- train: checkpoints in the artifact store (networks, optimisers, normalisers, replay buffers,
-- random generators, the environments' physics, the iteration); a killed run resumes from its
-- newest one.
CREATE TABLE train_checkpoints (
    key         VARCHAR NOT NULL,
    video_id    VARCHAR NOT NULL,
    iteration   INTEGER NOT NULL,
    artifact    VARCHAR NOT NULL,
    created_at  TIMESTAMP NOT NULL,
    PRIMARY KEY (key, video_id, iteration)
);

-- train: the committed result of a run: its final checkpoint.
CREATE TABLE train_policies (
    key         VARCHAR NOT NULL,
    video_id    VARCHAR NOT NULL,
    iteration   INTEGER NOT NULL,
    artifact    VARCHAR NOT NULL,
    PRIMARY KEY (key, video_id)
);
