-- pose: every person the detector found (score above the threshold), before tracking.
CREATE TABLE pose_detections (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    frame     INTEGER NOT NULL,
    score     DOUBLE NOT NULL,
    box       FLOAT[4] NOT NULL
);

-- pose: tracks with their role; roles are 'adversary', 'opponent' or 'other'.
CREATE TABLE pose_tracks (
    key             VARCHAR NOT NULL,
    video_id        VARCHAR NOT NULL,
    track           INTEGER NOT NULL,
    shot            INTEGER NOT NULL,
    role            VARCHAR NOT NULL CHECK (role IN ('adversary', 'opponent', 'other')),
    first_frame     INTEGER NOT NULL,
    last_frame      INTEGER NOT NULL,
    frames_observed INTEGER NOT NULL,
    PRIMARY KEY (key, video_id, track)
);

-- pose: where each track was seen, frame by frame.
CREATE TABLE pose_observations (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    frame     INTEGER NOT NULL,
    track     INTEGER NOT NULL,
    score     DOUBLE NOT NULL,
    box       FLOAT[4] NOT NULL,
    PRIMARY KEY (key, video_id, frame, track)
);

-- pose: each fighter's 33 BlazePose-order keypoints per frame, refined (x, y, confidence) and
-- as estimated (raw_*); track is -1 where the frame was filled in by refinement. world holds
-- the estimator's metric 3D points (x0, y0, z0, x1, ...), NaN when the backend gives none.
CREATE TABLE pose_keypoints (
    key            VARCHAR NOT NULL,
    video_id       VARCHAR NOT NULL,
    frame          INTEGER NOT NULL,
    role           VARCHAR NOT NULL CHECK (role IN ('adversary', 'opponent')),
    track          INTEGER NOT NULL,
    x              FLOAT[33] NOT NULL,
    y              FLOAT[33] NOT NULL,
    confidence     FLOAT[33] NOT NULL,
    raw_x          FLOAT[33] NOT NULL,
    raw_y          FLOAT[33] NOT NULL,
    raw_confidence FLOAT[33] NOT NULL,
    world          FLOAT[99] NOT NULL,
    PRIMARY KEY (key, video_id, role, frame)
);

-- pose: the review overlay (H.264 MP4) and stills, as artifact names.
CREATE TABLE pose_media (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    kind      VARCHAR NOT NULL CHECK (kind IN ('overlay', 'still')),
    frame     INTEGER NOT NULL,
    artifact  VARCHAR NOT NULL,
    PRIMARY KEY (key, video_id, kind, frame)
);

-- The analyst's choice of which track is the adversary, per video: an input of the pose stage,
-- not an output, so it is not keyed. The newest pick counts.
CREATE TABLE pose_picks (
    video_id   VARCHAR NOT NULL,
    track      INTEGER NOT NULL,
    picked_at  TIMESTAMP NOT NULL
);

-- Short messages a stage leaves for the analyst (e.g. "only one fighter found").
ALTER TABLE stage_outputs ADD COLUMN notes VARCHAR[] DEFAULT [];
