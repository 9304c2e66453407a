-- dataset: the clips cut from each video's motion, [start_step, end_step) on the lift's 30 Hz grid.
-- kind 'single' follows one fighter (role); 'interaction' both, agent 0 the adversary and agent 1
-- the opponent (MAAIP's M^S and M^I). split is 'train' or 'validation' (the end of each video).
CREATE TABLE dataset_clips (
    key         VARCHAR NOT NULL,
    video_id    VARCHAR NOT NULL,
    clip        INTEGER NOT NULL,
    kind        VARCHAR NOT NULL CHECK (kind IN ('single', 'interaction')),
    role        VARCHAR,
    shot        INTEGER NOT NULL,
    split       VARCHAR NOT NULL CHECK (split IN ('train', 'validation')),
    start_step  INTEGER NOT NULL,
    end_step    INTEGER NOT NULL,
    PRIMARY KEY (key, video_id, clip)
);

-- dataset: observation transitions (models.humanoid.observations). Single clips give
-- (o^self_t, o^self_t+1) with opp NULL; interaction clips give (o_t = [self, opp], o^self_t+1)
-- once per agent. An output's rows are inserted at once, in (kind, agent, clip, step) order, so
-- the rows of one output, kind and agent are contiguous and DuckDB's per-row-group min/max
-- indexes (zonemaps) skip everything else. No ART index: one on (key, video_id, kind, agent)
-- made writes 16 % slower and reads no faster (benchmarks/dataset_io.py).
CREATE TABLE dataset_transitions (
    key        VARCHAR NOT NULL,
    video_id   VARCHAR NOT NULL,
    kind       VARCHAR NOT NULL CHECK (kind IN ('single', 'interaction')),
    agent      TINYINT NOT NULL,  -- single clips: 0 adversary, 1 opponent, 2 extra clips
    split      VARCHAR NOT NULL CHECK (split IN ('train', 'validation')),
    clip       INTEGER NOT NULL,
    step       INTEGER NOT NULL,
    self       FLOAT[223] NOT NULL,
    opp        FLOAT[51],
    next_self  FLOAT[223] NOT NULL
);

-- dataset: punches found by the MSc thesis's labelling (Algorithms 1 and 2), steps on the 30 Hz
-- grid; the target is the wrist at full extension, in the world and, when the other fighter is
-- there, relative to its pelvis in its heading frame.
CREATE TABLE dataset_punches (
    key            VARCHAR NOT NULL,
    video_id       VARCHAR NOT NULL,
    role           VARCHAR NOT NULL,
    punch          INTEGER NOT NULL,
    hand           VARCHAR NOT NULL,
    kind           VARCHAR NOT NULL,
    start_step     INTEGER NOT NULL,
    peak_step      INTEGER NOT NULL,
    end_step       INTEGER NOT NULL,
    extension_m    DOUBLE NOT NULL,
    target         DOUBLE[3] NOT NULL,
    target_local   DOUBLE[3],
    PRIMARY KEY (key, video_id, role, punch)
);

-- dataset: steps from foot contacts.
CREATE TABLE dataset_steps (
    key             VARCHAR NOT NULL,
    video_id        VARCHAR NOT NULL,
    role            VARCHAR NOT NULL,
    foot            VARCHAR NOT NULL,
    lift_off_step   INTEGER NOT NULL,
    touch_down_step INTEGER NOT NULL,
    length_m        DOUBLE NOT NULL
);

-- dataset: each fighter's statistics (tasks.dataset.statistics), numbers and distributions.
CREATE TABLE dataset_statistics (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    role      VARCHAR NOT NULL,
    name      VARCHAR NOT NULL,
    value     DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, role, name)
);
CREATE TABLE dataset_distributions (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    role      VARCHAR NOT NULL,
    name      VARCHAR NOT NULL,
    samples   DOUBLE[] NOT NULL,
    PRIMARY KEY (key, video_id, role, name)
);

-- dataset: an assembled training set, everything training needs to know what it learned from:
-- its key (hash of the members' output keys and the settings), whose footage it is and which
-- per-video dataset outputs it joins.
CREATE TABLE datasets (
    dataset_key  VARCHAR PRIMARY KEY,
    adversary    VARCHAR NOT NULL,
    config       JSON NOT NULL,
    created_at   TIMESTAMP NOT NULL
);
CREATE TABLE dataset_members (
    dataset_key  VARCHAR NOT NULL,
    video_id     VARCHAR NOT NULL,
    key          VARCHAR NOT NULL,
    PRIMARY KEY (dataset_key, video_id)
);
