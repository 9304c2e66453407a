-- train: what a tracker run (train.objective 'track', models/maaip/tracking.py) made of its
-- dataset's footage, clip by clip: each interaction clip of both splits tracked from its first
-- frame by its fighter (agent 0 the adversary, 1 the opponent), acting on the policy's mean.
-- finished: it reached the clip's last frame without a fall or a drift; frames: the steps it
-- tracked; body_error_cm and root_error_cm: their mean errors (a data-quality measure: footage
-- a physics body cannot follow scores badly).
CREATE TABLE train_tracking (
    key            VARCHAR NOT NULL,
    video_id       VARCHAR NOT NULL,
    split          VARCHAR NOT NULL,
    agent          INTEGER NOT NULL,
    clip           VARCHAR NOT NULL,
    finished       BOOLEAN NOT NULL,
    frames         INTEGER NOT NULL,
    body_error_cm  DOUBLE NOT NULL,
    root_error_cm  DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id, split, agent, clip)
);
