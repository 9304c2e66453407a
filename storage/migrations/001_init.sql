-- Videos are identified by the SHA-256 of their bytes; the same footage under two names is one video.
CREATE TABLE videos (
    video_id      VARCHAR PRIMARY KEY,
    size_bytes    BIGINT NOT NULL,
    registered_at TIMESTAMP NOT NULL
);

-- Every path a video was registered from.
CREATE TABLE video_files (
    video_id      VARCHAR NOT NULL,
    path          VARCHAR NOT NULL,
    registered_at TIMESTAMP NOT NULL,
    PRIMARY KEY (video_id, path)
);

-- One row per committed stage output. It is written in the same transaction as the output's rows,
-- so its presence means the output is whole.
CREATE TABLE stage_outputs (
    stage         VARCHAR NOT NULL,
    video_id      VARCHAR NOT NULL,
    key           VARCHAR NOT NULL,
    config        JSON NOT NULL,
    code_version  VARCHAR NOT NULL,
    upstream      JSON NOT NULL,
    run_id        VARCHAR NOT NULL,
    seconds       DOUBLE NOT NULL,
    created_at    TIMESTAMP NOT NULL,
    PRIMARY KEY (stage, video_id, key)
);

-- What each run did with each stage: computed it (done), found it cached, or failed.
CREATE TABLE stage_runs (
    run_id        VARCHAR NOT NULL,
    video_id      VARCHAR NOT NULL,
    stage         VARCHAR NOT NULL,
    key           VARCHAR NOT NULL,
    state         VARCHAR NOT NULL CHECK (state IN ('done', 'cached', 'failed')),
    error         VARCHAR,
    created_at    TIMESTAMP NOT NULL
);

CREATE TABLE stage_metrics (
    run_id        VARCHAR NOT NULL,
    video_id      VARCHAR NOT NULL,
    stage         VARCHAR NOT NULL,
    key           VARCHAR NOT NULL,
    name          VARCHAR NOT NULL,
    value         DOUBLE NOT NULL,
    created_at    TIMESTAMP NOT NULL,
    PRIMARY KEY (stage, video_id, key, name)
);

-- ingest: what OpenCV found in the file.
CREATE TABLE ingest_probes (
    key             VARCHAR NOT NULL,
    video_id        VARCHAR NOT NULL,
    path            VARCHAR NOT NULL,
    fps             DOUBLE NOT NULL,
    frames          INTEGER NOT NULL,
    frames_declared INTEGER NOT NULL,
    width           INTEGER NOT NULL,
    height          INTEGER NOT NULL,
    codec           VARCHAR NOT NULL,
    duration_s      DOUBLE NOT NULL,
    PRIMARY KEY (key, video_id)
);

-- ingest: who the analyst says the adversary is in this video.
CREATE TABLE ingest_adversaries (
    key       VARCHAR NOT NULL,
    video_id  VARCHAR NOT NULL,
    name      VARCHAR NOT NULL,
    colour    VARCHAR,
    notes     VARCHAR,
    PRIMARY KEY (key, video_id)
);

-- ingest: shots between cuts, [start_frame, end_frame).
CREATE TABLE ingest_shots (
    key          VARCHAR NOT NULL,
    video_id     VARCHAR NOT NULL,
    shot         INTEGER NOT NULL,
    start_frame  INTEGER NOT NULL,
    end_frame    INTEGER NOT NULL,
    cut_distance DOUBLE,
    thumbnail    VARCHAR NOT NULL,  -- artifact name of a PNG of the shot's first frame
    PRIMARY KEY (key, video_id, shot)
);

-- ingest: the frame chunks later stages process, [start_frame, end_frame), never across a cut.
CREATE TABLE ingest_chunks (
    key          VARCHAR NOT NULL,
    video_id     VARCHAR NOT NULL,
    chunk        INTEGER NOT NULL,
    shot         INTEGER NOT NULL,
    start_frame  INTEGER NOT NULL,
    end_frame    INTEGER NOT NULL,
    PRIMARY KEY (key, video_id, chunk)
);
