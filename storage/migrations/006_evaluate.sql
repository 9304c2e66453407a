-- evaluate: every table is keyed by the evaluation's key; video_id holds the key of the training
-- run evaluated (its policies, bouts and exports). Definitions: tasks/evaluate/metrics.py.

-- evaluate: mean damage (N) per episode, received and dealt by each agent, over the evaluation
-- episodes (MAAIP Table 1): the evaluated run and every other finished run on its dataset whose
-- control task is damage_min or damage_max, each labelled by its train.reward.control_task.
CREATE TABLE evaluate_damage (
    key           VARCHAR NOT NULL,
    video_id      VARCHAR NOT NULL,
    run_key       VARCHAR NOT NULL,
    control_task  VARCHAR NOT NULL,
    agent         INTEGER NOT NULL,
    received_n    DOUBLE NOT NULL,
    dealt_n       DOUBLE NOT NULL,
    episodes      INTEGER NOT NULL,
    frames        INTEGER NOT NULL,
    PRIMARY KEY (key, video_id, run_key, agent)
);

-- evaluate: normalised heading return (MAAIP Table 2) of each finished heading run on the
-- dataset: the mean over episodes of the summed eq 11 reward over the episode's frames.
-- motion_prior: whether the run had the single motion prior (train.reward.w_motion > 0).
CREATE TABLE evaluate_heading (
    key                VARCHAR NOT NULL,
    video_id           VARCHAR NOT NULL,
    run_key            VARCHAR NOT NULL,
    motion_prior       BOOLEAN NOT NULL,
    agent              INTEGER NOT NULL,
    normalized_return  DOUBLE NOT NULL,
    episodes           INTEGER NOT NULL,
    frames             INTEGER NOT NULL,
    PRIMARY KEY (key, video_id, run_key, agent)
);

-- evaluate: style similarity per statistic of a simulated fighter against the adversary's real
-- statistics: policy 'adversary' (trained agent 0), 'untrained' (fresh networks' agent 0) or
-- 'opponent' (trained agent 1); kind 'rate', 'share' or 'distribution' (simulated and real hold
-- a distribution's mean, NaN when it is empty); distance in [0, 1], 0 identical.
CREATE TABLE evaluate_style (
    key        VARCHAR NOT NULL,
    video_id   VARCHAR NOT NULL,
    policy     VARCHAR NOT NULL,
    statistic  VARCHAR NOT NULL,
    kind       VARCHAR NOT NULL,
    simulated  DOUBLE NOT NULL,
    real       DOUBLE NOT NULL,
    distance   DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, policy, statistic)
);

-- evaluate: boxing metrics (MSc thesis §6.1) per simulated fighter, policy as in evaluate_style.
CREATE TABLE evaluate_boxing (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    policy    VARCHAR NOT NULL,
    metric    VARCHAR NOT NULL,
    value     DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, policy, metric)
);

-- evaluate: files in the artifact store: the adversary's opponent folder, one row per file
-- (name 'opponent/policy.onnx', 'opponent/manifest.json', ...), and the rendered bout
-- ('bout.mp4').
CREATE TABLE evaluate_artifacts (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    name      VARCHAR NOT NULL,
    artifact  VARCHAR NOT NULL,
    PRIMARY KEY (key, video_id, name)
);
